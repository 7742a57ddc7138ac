"""A regular-expression lexer for the PVL that PDS3 camera labels use, for ``pvl``'s parser.

``pvl`` reads a label a character at a time (~100 ms for a 22 kB Mastcam label). This module
cuts the same text into the same tokens with one compiled regular expression and hands them
to ``pvl``'s own parser (its documented ``lexer_fn`` hook), so parsing and value decoding stay
``pvl``'s. It covers the subset real labels use (assignments, GROUP/OBJECT blocks, quoted
strings, ``<units>``, ``/* comments */``, sequences, sets, ``radix#digits#`` numbers) and
refuses anything else by returning None from :func:`pvl_tokens`, so the caller falls back to
``pvl``'s lexer: characters ``pvl`` treats specially that labels do not use (``# & ' [ ] ! % ;
~ |`` and NUL), a quote or ``<`` glued to a word, ``*/`` inside a word, and comment markers in
quoted strings or units. ``tests/test_pvl_lexer.py`` checks token for token against ``pvl``'s
lexer on the real labels and on randomly damaged ones.
"""

from __future__ import annotations

import re
from collections.abc import Generator
from typing import Any

_DELIMITERS = r"[ \t\r\n\v\f{}(),=\"<>&'\[\]!#%;~|\x00]"
_TOKEN = re.compile(
    r"""
      (?P<space>[ \t\r\n\v\f]+)
    | (?P<comment>/\*.*?\*/)
    | (?P<quoted>"[^"]*")
    | (?P<units><[^<>"]*>)
    | (?P<reserved>[{}(),=])
    | (?P<radix>[+-]?[0-9]+\#[+-]?[0-9A-Za-z]+\#)
    | (?P<word>(?:(?!/\*)[^ \t\r\n\v\f{}(),="<>&'\[\]!#%;~|\x00])+)
    """,
    re.VERBOSE | re.DOTALL,
)
_STANDALONE = frozenset({"reserved", "comment"})  # may touch any neighbour, as in pvl
#: Push-backs the parser may make per token before a label counts as looping (see lexer).
PUSHBACKS_PER_TOKEN = 50


def pvl_tokens(text: str) -> list[tuple[str, int]] | None:
    """The (token, position) list ``pvl``'s lexer would give for ``text``, or None where the
    text leaves the subset this lexer handles (then use ``pvl``'s lexer)."""
    tokens: list[tuple[str, int]] = []
    kinds: list[str] = []
    pos, end, touching = 0, len(text), False
    while pos < end:
        match = _TOKEN.match(text, pos)
        if match is None:
            return None
        kind, token = match.lastgroup, match.group()
        if kind == "space":
            touching = False
        else:
            if kind in ("quoted", "units") and "/*" in token:
                return None
            if kind == "comment" and ("/" in token[2:-2] or "*" in token[2:-2]):
                return None  # pvl's comment ends are subtle around extra "/" and "*"
            if kind == "word" and "*/" in token:
                return None
            if touching and not _may_touch(kinds[-1], kind):
                return None
            if touching and kind == "comment" and tokens[-1][0].endswith("*"):
                return None  # pvl reads the "*/" of "x*/*...": a word ending in "*/"
            # pvl reports a comment one character before where it starts
            tokens.append((token, pos - 1 if kind == "comment" else pos))
            kinds.append(kind)
            touching = True
        pos = match.end()
    return tokens


def _may_touch(before: str, after: str) -> bool:
    """Whether pvl would also split two tokens with no space between them here."""
    if before in _STANDALONE or after in _STANDALONE:
        return True
    return before == "quoted"  # pvl ends a token at its closing quote


def lexer(text: str, g: Any, d: Any) -> Generator[Any, Any, None]:
    """A ``lexer_fn`` for ``pvl.parser.PVLParser``: pvl's tokens for ``text`` (from
    :func:`pvl_tokens`, else pulled one by one from pvl's own lexer), with pvl's protocol:
    ``send`` pushes a token back, and a ValueError thrown in by the parser comes out as pvl's
    LexerError at the current token.

    pvl's permissive parser can loop for ever on some damaged labels, pushing the same token
    back again and again; past ``PUSHBACKS_PER_TOKEN`` push-backs per token this raises a
    LexerError instead, so a damaged label fails instead of hanging a build.
    """
    from pvl.exceptions import LexerError
    from pvl.lexer import lexer as pvl_lexer

    regex_tokens = pvl_tokens(text)
    if regex_tokens is None:
        source: Any = pvl_lexer(text, g, d)  # pulled with next() only: plain pvl tokens
        budget = PUSHBACKS_PER_TOKEN * (len(text) // 4 + 1)
    else:
        token_class = _token_class()
        source = (token_class(t, grammar=g, decoder=d, pos=p) for t, p in regex_tokens)
        budget = PUSHBACKS_PER_TOKEN * (len(regex_tokens) + 1)
    for token in source:
        try:
            pushed = yield token
            while pushed is not None:
                budget -= 1
                if budget < 0:
                    raise ValueError("the parser stopped advancing (damaged label)")
                yield None
                pushed = yield pushed
        except ValueError as err:
            if isinstance(err, LexerError):
                raise
            raise LexerError(err, text, token.pos + len(token) - 1, token) from None


def _token_class() -> Any:
    """pvl's Token, with a direct whitespace-or-comment test valid for our tokens."""
    from pvl.token import Token

    class _Token(Token):  # type: ignore[misc]
        def is_WSC(self) -> bool:
            # our tokens hold no bare whitespace and no comment markers in quotes or words,
            # so "whitespace or comments" is "a comment" (pvl's test splits and re-tests)
            return self.is_comment()

    return _Token
