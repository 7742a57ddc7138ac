"""The label files a build's glob patterns match: streamed once each, in one total order.

Order: paths compared component by component (code points), the order of
``sorted(Path(p) for p in glob.glob(pattern, recursive=True))`` that the build used before, so
chunk k (labels ``[k*S, (k+1)*S)``) and the resume fingerprint are unchanged. Paths come out
as ``str(Path(p))`` writes them (POSIX separators).

Why not ``glob`` alone: ``glob.glob`` returns a list and ``glob.iglob`` streams in
``os.scandir`` order (the file system's, not sorted), so a total order needs ``sorted()`` over
every path at once: memory linear in the label count. Measured with
``benchmarks/bench_plan.py`` (planning 100,000 labels in 1,000 per-sol folders): glob +
``sorted`` + the chunk lists peak at 62 MiB (tracemalloc; 6 MiB at 10k) in 2.1 s, the plan
over this walk at 0.11 MiB (0.03 MiB at 10k) in 0.4 s (README, "Build planning"). Here one
folder is listed at a time (``os.scandir``), its names sorted, and the walk goes depth first:
sorted names within each folder, depth first, is the lexicographic order of path components,
so the stream is sorted without holding it; memory is bounded by the largest folder (its
matching names) times the depth. Several patterns are merged with ``heapq.merge`` and paths
matched by more than one pattern (adjacent in that order) come once.

glob's rules kept (``glob.glob(pattern, recursive=True)``): patterns are relative to the
current folder or absolute; ``*``, ``?`` and ``[...]`` match within one name (``fnmatch``); a
name starting with ``.`` is matched by a wildcard component only if the component starts with
``.`` too, and ``**`` neither matches nor enters hidden names; ``**`` as a whole component
matches zero or more folders (and, last, every file and folder below, plus the folder itself);
components before the last match folders only (symlinks followed), the last any entry; a
pattern ending in ``/`` matches folders only; a pattern without wildcards matches the path if
it exists. One deliberate difference: ``**`` does not enter a folder that is one of its own
ancestors (a symlink loop), where glob descends until the OS refuses the path (~40 levels),
listing the same files under ever longer names. An entry that cannot be stat'ed (a symlink
to itself, a loop of symlinks) is matched as a file, as glob does, never dropped: the build
then names it in a failure row, as it does a dangling symlink.
"""

from __future__ import annotations

import fnmatch
import heapq
import os
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import PurePath

_MAGIC = re.compile(r"[*?[]")  # glob.has_magic's characters


def path_key(path: str) -> tuple[str, ...]:
    """The sort key of ``str(Path)`` strings in ``Path`` order (Python 3.11's ``_cparts``):
    the components, an absolute path's first one being ``/``."""
    if path.startswith(os.sep):
        return (os.sep, *path[1:].split(os.sep))
    return tuple(path.split(os.sep))


def iter_matches(patterns: Iterable[str]) -> Iterator[str]:
    """Every path the glob ``patterns`` match, once, in ``Path`` order (see the module)."""
    streams = [_Pattern.parse(p).walk() for p in dict.fromkeys(patterns)]
    if len(streams) == 1:
        yield from streams[0]  # one walk yields each path once
        return
    previous = None
    for path in heapq.merge(*streams, key=path_key):
        if path != previous:
            yield path
        previous = path


@dataclass(frozen=True)
class _Part:
    """One pattern component: ``**``, a literal name, or a wildcard name."""

    text: str
    recursive: bool  # "**": zero or more folders
    match: Callable[[str], object] | None  # None: a literal name

    @classmethod
    def parse(cls, text: str) -> _Part:
        if text == "**":
            return cls(text, True, None)
        if not _MAGIC.search(text):
            return cls(text, False, None)
        return cls(text, False, re.compile(fnmatch.translate(text)).match)

    def matches(self, name: str) -> bool:
        """Whether this (non-``**``) component matches ``name``, hidden names as glob does."""
        if self.match is None:
            return name == self.text
        if name.startswith(".") and not self.text.startswith("."):
            return False
        return self.match(name) is not None


@dataclass(frozen=True)
class _Pattern:
    """A glob pattern as a literal root folder and the components matched below it: a small
    automaton whose states are the index of the next component to match."""

    root: str  # the literal leading folders as str(Path) writes them; "" = the current folder
    parts: tuple[_Part, ...]
    dir_only: bool  # the pattern ends with a separator: folders only

    @classmethod
    def parse(cls, pattern: str) -> _Pattern:
        dir_only = pattern.endswith(os.sep) or (os.altsep is not None and pattern.endswith("/"))
        names = PurePath(pattern).parts if pattern else ()
        first = next((i for i, n in enumerate(names) if _MAGIC.search(n)), len(names))
        root = str(PurePath(*names[:first])) if first else ""
        return cls(root, tuple(_Part.parse(n) for n in names[first:]), dir_only)

    def walk(self) -> Iterator[str]:
        """The matching paths, depth first, names sorted within each folder."""
        if not self.parts:  # no wildcard: the path itself, if it exists
            if self.root and _exists(self.root, self.dir_only):
                yield self.root
            return
        start = self._closure({0})
        if len(self.parts) in start and self.root and os.path.isdir(self.root):
            yield self.root  # "root/**" matches root itself, as glob's "root/"
        states = frozenset(start - {len(self.parts)})
        ancestors = self._enter(self.root or os.curdir, states, ())
        if ancestors is not None:
            yield from self._walk(self.root, states, ancestors)

    def _walk(
        self, folder: str, states: frozenset[int], ancestors: tuple[tuple[int, int], ...]
    ) -> Iterator[str]:
        names, dirs = self._names(folder, states)
        for name in names:
            is_dir = name in dirs
            final, after = self._step(states, name, is_dir)
            path = _join(folder, name)
            if final:
                yield path
            if after and is_dir:
                inner = self._enter(path, after, ancestors)
                if inner is not None:
                    yield from self._walk(path, after, inner)

    def _enter(
        self, folder: str, states: frozenset[int], ancestors: tuple[tuple[int, int], ...]
    ) -> tuple[tuple[int, int], ...] | None:
        """The folder ids on the way down, or None when ``**`` would enter one of them again
        (a symlink loop). Only ``**`` can loop, so only its folders are stat'ed."""
        if not any(self.parts[i].recursive for i in states):
            return ancestors
        try:
            st = os.stat(folder)
        except OSError:
            return None
        ident = (st.st_dev, st.st_ino)
        return None if ident in ancestors else (*ancestors, ident)

    def _names(self, folder: str, states: frozenset[int]) -> tuple[list[str], set[str]]:
        """The sorted names in ``folder`` that match or lead to a match, and which of them
        are folders: its listing when a state is a wildcard or ``**``, plus the literal names
        that exist (checked, like glob, by lstat, so ``..`` works). Only these names are
        kept, so a folder's other files (the images beside the labels) cost no memory.
        Unreadable folders give nothing, as in glob."""
        names: list[str] = []
        dirs: set[str] = set()
        if any(self.parts[i].match is not None or self.parts[i].recursive for i in states):
            try:
                with os.scandir(folder or os.curdir) as entries:
                    for entry in entries:
                        try:
                            is_dir = entry.is_dir()
                        except OSError:  # a symlink loop: offered as a file, so the
                            is_dir = False  # build names it in a failure row
                        final, after = self._step(states, entry.name, is_dir)
                        if final or (after and is_dir):
                            names.append(entry.name)
                            if is_dir:
                                dirs.add(entry.name)
            except OSError:
                return [], set()
        literals = [
            self.parts[i].text
            for i in states
            if self.parts[i].match is None and not self.parts[i].recursive
        ]
        if literals:
            present = set(names)
            for name in dict.fromkeys(literals):
                path = _join(folder, name)
                if name not in present and os.path.lexists(path):
                    names.append(name)
                    if os.path.isdir(path):
                        dirs.add(name)
        names.sort()
        return names, dirs

    def _step(self, states: frozenset[int], name: str, is_dir: bool) -> tuple[bool, frozenset[int]]:
        """Whether ``name`` in a folder reached with ``states`` matches the whole pattern, and
        the states to walk its contents with (empty: do not enter it)."""
        last = len(self.parts) - 1
        final = False
        after: set[int] = set()
        for i in states:
            part = self.parts[i]
            if part.recursive:
                if name.startswith("."):
                    continue
                final = final or i == last  # a last "**" matches files and folders
                if is_dir:
                    after.add(i)
            elif part.matches(name):
                final = final or i == last
                if is_dir and i < last:
                    after.add(i + 1)
        closed = self._closure(after)
        final = final or last + 1 in closed  # only folders get here: "**" matching none
        if self.dir_only and not is_dir:
            final = False
        return final, frozenset(closed - {last + 1})

    def _closure(self, states: set[int]) -> set[int]:
        """``states`` plus the states reached by letting each ``**`` match no folder."""
        closed = set(states)
        todo = list(states)
        while todo:
            i = todo.pop()
            if i < len(self.parts) and self.parts[i].recursive and i + 1 not in closed:
                closed.add(i + 1)
                todo.append(i + 1)
        return closed


def _join(folder: str, name: str) -> str:
    if not folder:
        return name
    return folder + name if folder.endswith(os.sep) else folder + os.sep + name


def _exists(path: str, dir_only: bool) -> bool:
    if dir_only:
        return os.path.isdir(path)
    try:
        os.lstat(path)
    except (OSError, ValueError):
        return False
    return True
