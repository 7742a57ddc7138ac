"""``mars-pairs fetch`` on the command line; a fetch killed mid-download and rerun."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from mars_pairs.cli.main import main
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.run import fetch_products
from support import fetch_archive
from support.fetch_archive import write_config
from support.fetch_server import ArchiveServer

REPO = Path(__file__).resolve().parents[2]


def test_dry_run_prints_count_and_bytes(archive, tmp_path, capsys):
    with ArchiveServer(archive.root) as srv:
        config = write_config(tmp_path, srv.url, "m2020")
        status = main(["fetch", "products", "--config", str(config), "--dry-run", "--quiet"])
    sizes = sum(p.with_suffix(".jpg").stat().st_size for p in archive.m2020_labels)
    assert status == 0
    assert capsys.readouterr().out.strip() == (
        f"dry run: 4 products (4 listed), {sizes} image bytes, {sizes} not yet in the cache; "
        "0 failures, 1 skipped\n  skipped 1: secondary member"  # the inventory's S row
    )


def test_cli_filters_and_failures_exit_1_with_one_line_per_url(archive, tmp_path, capsys):
    with ArchiveServer(archive.root) as srv:
        config = write_config(tmp_path, srv.url, "msl")
        label = archive.msl_labels[0].relative_to(archive.root)
        srv.fault(str(label), "404")
        argv = ["fetch", "products", "--config", str(config), "--sol", "1429", "1429", "--quiet"]
        assert main(argv) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [
            f"mars-pairs fetch: {srv.url}/{label}: HTTP 404 NOT FOUND (not in the archive)"
        ]
        assert main(argv) == 0  # the rerun completes
        assert "2 products (2 listed)" in capsys.readouterr().out


def test_bad_config_exits_2_naming_the_key(tmp_path, capsys):
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"fetch": {"cache": "c", "workers": 0}}))
    assert main(["fetch", "products", "--config", str(config)]) == 2
    assert "fetch.workers" in capsys.readouterr().err


def test_a_fetch_killed_mid_download_resumes_and_fetches_only_what_was_missing(archive, tmp_path):
    with ArchiveServer(archive.root, slow_s=30.0) as srv:
        config = write_config(tmp_path, srv.url, "m2020", sols=[54, 54])
        doc = yaml.safe_load(config.read_text())
        doc["fetch"].update({"workers": 1, "timeout_s": 60})
        config.write_text(yaml.safe_dump(doc))
        cfg = load_fetch_config(config)
        # products go in index order with one worker: stall the last image half-way
        last = sorted(p for p in archive.m2020_labels if "_0054_" in p.name)[-1]
        image = last.with_suffix(".jpg").relative_to(archive.root)
        srv.fault(str(image), "stall")
        part = cfg.cache / image.relative_to("mars2020")
        part = part.with_name(part.name + ".part")
        env = dict(os.environ, PYTHONPATH=str(REPO))
        cmd = [sys.executable, "-m", "mars_pairs.cli", "fetch", "products", "--config",
               str(config), "--quiet"]  # fmt: skip
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 60
            while not (part.is_file() and part.stat().st_size > 0):
                assert proc.poll() is None, proc.stderr.read().decode()  # type: ignore[union-attr]
                assert time.monotonic() < deadline, "the fetch never reached the stalled image"
                time.sleep(0.05)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
        kept = part.stat().st_size
        assert not part.with_suffix("").exists()  # no half-written file under the real name
        srv.reset_log()
        report = fetch_products(cfg, progress=False)
        gets = [e for e in srv.log if e.method == "GET" and e.status != 304]  # 304: tables
    assert report.selected == 2 and not report.failures
    assert [(e.path, e.range) for e in gets] == [(f"/{image}", f"bytes={kept}-")]
    data = (cfg.cache / image.relative_to("mars2020")).read_bytes()
    assert (
        hashlib.md5(data).hexdigest()
        == hashlib.md5((archive.root / image).read_bytes()).hexdigest()
    )


def test_fetch_all_lays_out_what_a_build_reads(archive, tmp_path, capsys):
    with ArchiveServer(archive.root) as srv:
        config = write_config(tmp_path, srv.url, "msl")
        doc = yaml.safe_load(config.read_text())
        base = f"{srv.url}/orbital/msl"
        doc["fetch"]["orbital"] = {"dem": f"{base}/dem_cog.tif", "ortho": f"{base}/ortho_cog.tif"}
        config.write_text(yaml.safe_dump(doc))
        assert main(["fetch", "all", "--config", str(config), "--quiet"]) == 0
    cache = tmp_path / "cache"
    assert (cache / fetch_archive.MSL_PLACES).is_file()
    assert len(list(cache.glob("MSLMST_0001/DATA/RDR/SURFACE/*/*.LBL"))) == 4
    assert len(list(cache.glob("MSLMST_0001/DATA/RDR/SURFACE/*/*.jpg"))) == 4
    assert (cache / "orbital" / "dem.tif").is_file() and (cache / "orbital" / "ortho.tif").is_file()
    out = capsys.readouterr().out
    assert "4 products (4 listed)" in out and "orbital/dem.tif" in out


def test_an_unreachable_archive_is_one_line_and_a_failure_row(tmp_path, capsys):
    """Each volume's index is fetched on its own: an unreachable one is a failure row (exit 1)
    naming its URL, and the other volumes would go on."""
    config = write_config(tmp_path, "http://127.0.0.1:9", "msl")  # discard port: refused
    assert main(["fetch", "products", "--config", str(config), "--quiet"]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "http://127.0.0.1:9/msl/MSLMST_0001/INDEX/RDRINDEX.LBL" in err[0]
    assert "0 products (0 listed)" in captured.out and "1 failures" in captured.out


def test_fetch_all_runs_the_sections_the_config_has(archive, tmp_path, capsys):
    with ArchiveServer(archive.root) as srv:
        config = write_config(tmp_path, srv.url, "m2020")  # no orbital section
        assert main(["fetch", "all", "--config", str(config), "--quiet"]) == 0
    assert (tmp_path / "cache" / fetch_archive.M2020_PLACES).is_file()
    assert "4 products (4 listed)" in capsys.readouterr().out


def test_an_offline_dry_run_fails_fast_writes_nothing_and_exits_alike(
    tmp_path, capsys, monkeypatch
):
    """A host name that does not resolve (offline) is not retried; a dry run writes no file;
    both missions' configs exit with the same status."""
    import urllib3.util.retry

    sleeps = []
    monkeypatch.setattr(urllib3.util.retry.Retry, "sleep", lambda self, *a: sleeps.append(1))
    statuses = {}
    for mission in ("msl", "m2020"):
        folder = tmp_path / mission
        folder.mkdir()
        config = write_config(folder, "https://no-such-host.invalid", mission)
        before = sorted(folder.rglob("*"))
        statuses[mission] = main(["fetch", "all", "--config", str(config), "--dry-run", "--quiet"])
        err = capsys.readouterr().err
        assert "host name not resolved (offline?)" in err and "retries" not in err, err
        assert sorted(folder.rglob("*")) == before  # no failure file, no cache folder
    assert statuses["msl"] == statuses["m2020"] != 0, statuses
    assert sleeps == []  # no backoff: nothing was retried
