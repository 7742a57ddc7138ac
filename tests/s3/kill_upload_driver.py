"""Build a generated mission into an S3 prefix and die mid-upload: ``python
kill_upload_driver.py MISSION URL TARGET``.

Run by tests/s3/test_s3_build.py in a fresh process (a fork of the test process, whose numba
OpenMP threads run, is unsafe). The build runs in this process (one worker: the process
that uploads is the one killed). The upload of the object whose name holds TARGET starts a
multipart upload on the server, sends the first half of the file and SIGKILLs this process:
the upload is never completed, as when a worker dies mid-upload. Every other upload runs.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.store import fs
from support.builds import small_doc


def main(mission: Path, url: str, target: str) -> None:
    real = fs.upload

    def upload(local: Path, path: str) -> None:
        if target not in path:
            real(local, path)
            return
        filesystem, key = fs.filesystem(path)
        bucket, name = key.split("/", 1)
        data = local.read_bytes()
        mpu = filesystem.call_s3("create_multipart_upload", Bucket=bucket, Key=name)
        filesystem.call_s3(
            "upload_part",
            Bucket=bucket,
            Key=name,
            UploadId=mpu["UploadId"],
            PartNumber=1,
            Body=data[: len(data) // 2],
        )
        os.kill(os.getpid(), signal.SIGKILL)

    fs.upload = upload  # type: ignore[assignment]
    doc = small_doc(mission, Path("/unused"))
    doc["output"]["dir"] = url
    run_build(parse_config(doc, base=mission), progress=False)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], sys.argv[3])
