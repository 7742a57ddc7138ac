"""``mars-pairs report``: the HTML page of a small built dataset, rendered in headless Chromium.

Chromium is driven over its DevTools protocol (a small WebSocket client below, standard
library only): the page loads with no console message, no script error and no request but
``file:`` and ``data:`` ones; every image decodes; the rendered tables show the manifest's
split counts and the failures of failures.parquet. Skipped when Chromium is absent, unless
``MARS_PAIRS_REQUIRE_CHROMIUM`` is set (CI sets it), which makes its absence a failure.
"""

from __future__ import annotations

import base64
import csv
import io
import json
import os
import shutil
import socket
import struct
import subprocess
import time
import urllib.request
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import yaml
from PIL import Image

from mars_pairs.cli.main import main
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from support.configs import config_file, mission_inputs
from support.missions import MissionCache

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

pytest.importorskip("matplotlib")

BROKEN = ("ZZ_truncated.xml", "ZZ_random.xml")


@pytest.fixture(scope="module")
def dataset(missions: MissionCache, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """4 samples (2 stops x 2 images 26 m apart), the first stop in a held-out test area,
    and 2 broken labels (failures)."""
    tmp = tmp_path_factory.mktemp("report")
    mission = missions.copy(tmp / "mission", seed=5, stops=2, images_per_stop=2)
    labels = mission / "labels"
    text = sorted(labels.glob("*.xml"))[0].read_text()
    (labels / BROKEN[0]).write_text(text[: len(text) // 2])
    (labels / BROKEN[1]).write_bytes(bytes(range(256)) * 2)
    splits = {"style": "cross-area", "areas": {"test": [first_stop_box(mission, 3.0)]},
              "guard": "chip", "buffer_m": 1}  # fmt: skip
    config_file(
        tmp / "c.yaml", mission, tmp / "ds", fine=True, geometry={"radius": 400},
        chips={"size_m": 24, "size_px": 64}, output={"shard_size": 2}, whole={"splits": splits},
    )  # fmt: skip
    summary = run_build(load_config(tmp / "c.yaml"), workers=1, progress=False)
    assert summary.samples == 4 and summary.failures == len(BROKEN)
    return tmp / "ds"


def first_stop_box(mission: Path, half: float) -> list[float]:
    """A map box (dataset CRS) of ``half`` metres around the mission's first rover stop."""
    with open(mission / "places" / "best_interp.csv") as fh:
        rover = next(r for r in csv.DictReader(fh) if r["frame"] == "ROVER")
    x, y = float(rover["easting"]), float(rover["northing"])
    return [x - half, y - half, x + half, y + half]


# -- a headless Chromium over the DevTools protocol ---------------------------------------------


def chromium_path() -> str:
    """The Chromium executable; skip (or fail, with MARS_PAIRS_REQUIRE_CHROMIUM) without one."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        if os.environ.get("MARS_PAIRS_REQUIRE_CHROMIUM"):
            pytest.fail("chromium not found and MARS_PAIRS_REQUIRE_CHROMIUM is set")
        pytest.skip("chromium not installed (apt-get install chromium)")
    return found


class DevTools:
    """One page target of a browser, driven by DevTools protocol calls over a WebSocket."""

    def __init__(self, ws_url: str, timeout: float = 60.0) -> None:
        rest = ws_url.split("://", 1)[1]
        host_port, path = rest.split("/", 1)
        host, port = host_port.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET /{path} HTTP/1.1\r\nHost: {host_port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            "Sec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(1)
            assert chunk, "DevTools closed the connection during the handshake"
            head += chunk
        assert head.startswith(b"HTTP/1.1 101"), head
        self.events: list[dict[str, Any]] = []
        self._next = 0

    def _read(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            assert chunk, "DevTools closed the connection"
            data += chunk
        return data

    def _send(self, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        if n < 126:
            head = struct.pack("!BB", 0x81, 0x80 | n)
        elif n < 1 << 16:
            head = struct.pack("!BBH", 0x81, 0x80 | 126, n)
        else:
            head = struct.pack("!BBQ", 0x81, 0x80 | 127, n)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(head + mask + masked)

    def _message(self) -> dict[str, Any]:
        parts = []
        while True:
            b0, b1 = self._read(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack("!H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack("!Q", self._read(8))[0]
            payload = self._read(n)
            opcode = b0 & 0x0F
            assert opcode != 0x8, "DevTools closed the WebSocket"
            if opcode in (0x0, 0x1, 0x2):
                parts.append(payload)
                if b0 & 0x80:
                    return json.loads(b"".join(parts))

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        """The result of one protocol call; events received meanwhile go to ``events``."""
        self._next += 1
        self._send(json.dumps({"id": self._next, "method": method, "params": params}).encode())
        while True:
            msg = self._message()
            if msg.get("id") == self._next:
                assert "error" not in msg, (method, msg["error"])
                return msg["result"]
            if "method" in msg:
                self.events.append(msg)

    def wait_for(self, event: str, timeout: float = 60.0) -> None:
        end = time.monotonic() + timeout
        while not any(e["method"] == event for e in self.events):
            assert time.monotonic() < end, f"no {event} within {timeout} s"
            msg = self._message()
            if "method" in msg:
                self.events.append(msg)

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"]["value"]

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[DevTools]:
    """A headless Chromium on about:blank with a throwaway profile, its page target attached."""
    exe = chromium_path()
    profile = tmp_path / "profile"
    log = open(tmp_path / "chromium.log", "wb")  # noqa: SIM115 (closed below)
    proc = subprocess.Popen(
        [
            exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
            "--no-first-run", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--disable-extensions", f"--user-data-dir={profile}",
            "--remote-debugging-port=0", "--remote-debugging-address=127.0.0.1",
            "--window-size=1400,1000", "about:blank",
        ],
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )  # fmt: skip
    tools = None
    try:
        active = profile / "DevToolsActivePort"
        end = time.monotonic() + 60
        while not (active.is_file() and active.read_text().count("\n") >= 1):
            assert proc.poll() is None, (tmp_path / "chromium.log").read_text(errors="replace")
            assert time.monotonic() < end, "chromium wrote no DevToolsActivePort in 60 s"
            time.sleep(0.1)
        port = int(active.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=30) as resp:
            targets = json.load(resp)
        page = next(t for t in targets if t["type"] == "page")
        tools = DevTools(page["webSocketDebuggerUrl"])
        yield tools
    finally:
        if tools is not None:
            tools.close()
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=20)
        log.close()


def render(tools: DevTools, page: Path, screenshot: Path | None = None) -> dict[str, Any]:
    """Load ``page`` and return what the browser made of it: console messages, requests,
    images, the split and failures tables; write a full-page PNG to ``screenshot``."""
    for domain in ("Runtime", "Log", "Page", "Network"):
        tools.call(f"{domain}.enable")
    tools.call("Page.navigate", url=page.resolve().as_uri())
    tools.wait_for("Page.loadEventFired")
    seen = tools.evaluate(
        """JSON.stringify({
        images: [...document.images].map(i => [i.alt, i.complete, i.naturalWidth,
                                               i.naturalHeight, i.getBoundingClientRect().width]),
        text: document.body.innerText,
        splits: [...document.querySelectorAll('#splits table:first-of-type tbody tr')]
                 .map(r => [...r.cells].map(c => c.innerText.trim())),
        failures: [...document.querySelectorAll('#failures table')].map(t =>
                 [...t.querySelectorAll('tbody tr')].map(r =>
                   [...r.cells].map(c => c.innerText.trim()))),
        width: document.documentElement.scrollWidth,
        height: document.documentElement.scrollHeight,
        scripts: document.scripts.length})"""
    )
    out = json.loads(seen)
    if screenshot is not None:
        shot = tools.call(
            "Page.captureScreenshot",
            format="png",
            captureBeyondViewport=True,
            clip={"x": 0, "y": 0, "width": 1400, "height": out["height"], "scale": 1},
        )
        screenshot.write_bytes(base64.b64decode(shot["data"]))
    tools.call("Page.navigate", url="about:blank")
    events = tools.events
    out["console"] = [e["params"] for e in events if e["method"] == "Runtime.consoleAPICalled"]
    out["console"] += [
        e["params"]
        for e in events
        if e["method"] == "Log.entryAdded" and e["params"]["entry"]["level"] in ("error", "warning")
    ]
    out["exceptions"] = [e["params"] for e in events if e["method"] == "Runtime.exceptionThrown"]
    out["requests"] = [
        e["params"]["request"]["url"] for e in events if e["method"] == "Network.requestWillBeSent"
    ]
    out["failed"] = [e["params"] for e in events if e["method"] == "Network.loadingFailed"]
    return out


# -- the tests ----------------------------------------------------------------------------------


def test_report_renders_in_chromium(
    dataset: Path, tmp_path: Path, browser: DevTools, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "site" / "report.html"
    assert main(["report", str(dataset), "--out", str(out), "--samples", "3"]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    page = render(browser, out, tmp_path / "report.png")

    assert page["console"] == [] and page["exceptions"] == [], (page["console"], page["exceptions"])
    assert page["failed"] == [], page["failed"]
    assert page["scripts"] == 0
    schemes = {url.split(":", 1)[0] for url in page["requests"]}
    assert schemes <= {"file", "data"}, page["requests"]
    # the map, the histograms and 3 gallery cards, each decoded and laid out
    images = page["images"]
    assert len(images) == 2 + 3, images
    for alt, complete, width, height, shown in images:
        assert complete and width > 100 and height > 100 and shown > 100, alt
    # the split table holds the manifest's counts; the last row is the total
    splits = Counter(pq.read_table(dataset / "manifest.parquet")["split"].to_pylist())
    assert splits == {"test": 2, "train": 2}
    rows = page["splits"]
    assert {r[0]: int(r[1]) for r in rows[:-1]} == dict(splits)
    assert rows[-1][:2] == ["all", str(sum(splits.values()))]
    # the failures: counts by reason, then one row per failed product, naming its file
    by_reason, listed = page["failures"]
    assert by_reason == [["label", "LabelError", str(len(BROKEN))]]
    assert sorted(r[4] for r in listed) == sorted(BROKEN)
    assert all(r[1] == "label" and r[2] == "LabelError" and r[3] for r in listed)
    text = page["text"]
    for words in ("4 samples, 2 failures", "Provenance", "mars_pairs", "build time"):
        assert words in text, words
    with Image.open(tmp_path / "report.png") as shot:
        assert shot.size == (1400, page["height"]) and page["width"] <= 1400
        assert len(shot.convert("L").getcolors(1 << 16) or []) > 50  # drawn, not blank


def test_report_is_one_file_with_inline_images(dataset: Path) -> None:
    assert main(["report", str(dataset), "--samples", "0"]) == 0
    path = dataset.parent / "ds-report.html"  # beside the dataset folder, not in it
    assert not (dataset / "report.html").exists()
    text = path.read_text()
    assert "<script" not in text and "http://" not in text and "https://" not in text
    assert text.count('src="data:image/png;base64,') == 2  # the map and the histograms
    for raw in text.split('src="data:image/png;base64,')[1:]:
        with Image.open(io.BytesIO(base64.b64decode(raw.split('"', 1)[0]))) as im:
            assert im.format == "PNG" and min(im.size) > 100
    assert not [p.name for p in dataset.parent.iterdir() if ".tmp" in p.name]  # atomically


def test_report_of_a_dataset_without_samples_lists_its_failures(
    dataset: Path, tmp_path: Path
) -> None:
    config = yaml.safe_load((dataset.parent / "c.yaml").read_text())
    mission = dataset.parent / "mission"
    config["inputs"] = mission_inputs(mission, labels=mission / "labels" / "ZZ_*.xml")
    config["output"]["dir"] = str(tmp_path / "empty")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(config))
    summary = run_build(load_config(tmp_path / "c.yaml"), workers=1, progress=False)
    assert summary.samples == 0 and summary.failures == len(BROKEN)
    out = tmp_path / "empty.html"
    assert main(["report", str(tmp_path / "empty"), "--out", str(out)]) == 0
    text = out.read_text()
    assert "0 samples, 2 failures" in text and "no samples: nothing to draw" in text
    assert all(name in text for name in BROKEN) and "<img" not in text


def test_report_without_the_orthoimage_still_draws_the_map(dataset: Path, tmp_path: Path) -> None:
    moved = tmp_path / "moved"
    shutil.copytree(dataset, moved)
    info = json.loads((moved / "dataset.json").read_text())
    info["config"]["inputs"]["ortho"] = str(tmp_path / "gone" / "ortho.tif")
    (moved / "dataset.json").write_text(json.dumps(info))
    assert main(["report", str(moved), "--samples", "1"]) == 0
    assert (tmp_path / "moved-report.html").read_text().count('src="data:image/png;base64,') == 3


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["report", "{tmp}/missing"], "missing"),
        (["report", "{tmp}", "--out", "{tmp}/x.html"], "manifest.parquet"),
    ],
)
def test_report_bad_input_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], expected: str
) -> None:
    args = [a.format(tmp=tmp_path) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err and err.startswith("mars-pairs report: "), err
    assert not (tmp_path / "x.html").exists()


def test_report_rejects_a_negative_sample_count(dataset: Path) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["report", str(dataset), "--samples", "-1"])
    assert exc.value.code == 2


def test_gallery_wedges_start_at_the_camera_centre(
    dataset: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each gallery card's wedge apex is the sample's camera centre (meta.json), not the rover;
    the centres of all cards come from one read of the manifest."""
    import json

    from mars_pairs.report import meta as report_meta
    from mars_pairs.report import write_report
    from mars_pairs.store.query import Manifest
    from mars_pairs.store.shards import MemberLocation, read_member
    from mars_pairs.viz import report_figures, sample

    apexes: list[tuple[float, float]] = []
    original = sample.wedge_pixels

    def spy(row, inv):  # type: ignore[no-untyped-def]
        x0, y0, known = sample.wedge_apex(row)
        assert known, "no camera centre reached the card"
        apexes.append((x0, y0))
        return original(row, inv)

    opened: list[Path] = []

    class CountingManifest:
        @staticmethod
        def open(root: Path) -> Manifest:
            opened.append(root)
            return Manifest.open(root)

    monkeypatch.setattr(report_figures, "wedge_pixels", spy)  # the card's own reference
    monkeypatch.setattr(report_meta, "Manifest", CountingManifest)
    write_report(dataset, out=dataset.parent / "gallery-check.html", samples=2)
    assert len(apexes) == 2 and len(opened) == 1, (apexes, opened)
    rows = Manifest.open(dataset).to_table(
        columns=["key", "meta_shard", "meta_offset", "meta_size"]
    )
    centres = []
    for r in rows.to_pylist():
        loc = MemberLocation(r["meta_shard"], int(r["meta_offset"]), int(r["meta_size"]))
        meta = json.loads(read_member(dataset, loc, name=f"{r['key']}.meta.json"))
        centres.append(tuple(meta["camera_center_map"][:2]))
    assert apexes and all(a in centres for a in apexes)


def test_the_tools_outputs_never_block_the_next_build(
    dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """report, overview and export-qgis write beside the dataset folder by default and refuse
    a path inside it; a rebuild of the same config then works."""
    config = yaml.safe_load((dataset.parent / "c.yaml").read_text())
    config["output"]["dir"] = str(tmp_path / "ds")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(config))
    assert main(["build", "--config", str(tmp_path / "c.yaml"), "--quiet"]) == 0
    ds = tmp_path / "ds"
    before = sorted(p.relative_to(ds).as_posix() for p in ds.rglob("*"))
    assert main(["report", str(ds), "--samples", "1"]) == 0
    assert main(["overview", str(ds)]) == 0
    assert main(["export-qgis", str(ds)]) == 0
    for name in ("ds-report.html", "ds-overview.png", "ds-qgis.gpkg"):
        assert (tmp_path / name).is_file(), name
    assert sorted(p.relative_to(ds).as_posix() for p in ds.rglob("*")) == before
    capsys.readouterr()
    for argv in (
        ["report", str(ds), "--out", str(ds / "report.html")],
        ["overview", str(ds), "--out", str(ds / "sub" / "o.png")],
        ["export-qgis", str(ds), str(ds / "q.gpkg")],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "inside the dataset folder" in err and "beside the folder" in err, err
    assert sorted(p.relative_to(ds).as_posix() for p in ds.rglob("*")) == before
    # the same config builds again over its own folder (not --resume: a rebuild)
    assert main(["build", "--config", str(tmp_path / "c.yaml"), "--quiet"]) == 0


def test_the_report_and_dataset_json_record_the_libraries_and_speak_plainly(
    dataset: Path, tmp_path: Path
) -> None:
    versions = json.loads((dataset / "dataset.json").read_text())["versions"]
    for name in ("gdal", "proj", "torch", "pillow", "imagecodecs", "rasterio", "numba"):
        assert versions[name] not in ("", "-"), name
    assert versions["torch"].startswith("2.")
    out = tmp_path / "r.html"
    assert main(["report", str(dataset), "--out", str(out), "--samples", "0"]) == 0
    text = out.read_text()
    for name in ("gdal", "proj", "imagecodecs", "pillow", "torch"):
        assert f"<td>{name}</td>" in text, name
    for raw in ("True", "False", "[]", "None", "{}"):
        assert f"<td>{raw}</td>" not in text, raw
    assert "<td>warnings</td><td>none</td>" in text
    assert "<td>guaranteed</td><td>yes: buffer" in text or "<td>guaranteed</td><td>no: " in text
