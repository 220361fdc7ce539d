"""Content hashes and stage markers: what makes a stage of the chain up to date.

A stage's *input hash* is the SHA-256 of its settings (a JSON-ready dict) together with the output hashes of the
stages it reads. When a stage finishes, DIR/stages/<name>.json records that input hash, the SHA-256 of each
output file, its wall time (s) and when it ended. A stage is up to date when that record exists, its input hash
equals the one computed now and every output file still has the recorded hash. While a stage runs,
DIR/stages/<name>.running.json holds its input hash: a restart with the same inputs resumes the stage's
partial work (training checkpoints, traced PSF chunks); with other inputs that work is deleted first.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from aat_deploy.io.atomic import write_text_atomic


def file_sha256(path, chunk: int = 1 << 20) -> str:
    """SHA-256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()


def dict_sha256(d) -> str:
    """SHA-256 (hex) of a JSON-serialisable value, key order ignored."""
    return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()


def write_json_atomic(path, obj) -> None:
    """Write JSON through a temporary file and a rename (a kill never leaves half a file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(obj, indent=1) + "\n")


class StageMarkers:
    """The records of one run folder's stages (DIR/stages/)."""

    def __init__(self, run_dir):
        self.run_dir = Path(run_dir)
        self.dir = self.run_dir / "stages"

    def done_path(self, stage: str) -> Path:
        return self.dir / f"{stage}.json"

    def running_path(self, stage: str) -> Path:
        return self.dir / f"{stage}.running.json"

    def record(self, stage: str) -> dict | None:
        """The completion record of `stage`, or None."""
        p = self.done_path(stage)
        try:
            return json.loads(p.read_text()) if p.is_file() else None
        except json.JSONDecodeError:
            return None

    def up_to_date(self, stage: str, input_hash: str) -> bool:
        rec = self.record(stage)
        if rec is None or rec.get("input_hash") != input_hash:
            return False
        for rel, sha in rec.get("outputs", {}).items():
            p = self.run_dir / rel
            if not p.is_file() or file_sha256(p) != sha:
                return False
        return True

    def output_hashes(self, stage: str) -> dict[str, str]:
        rec = self.record(stage)
        return dict(rec.get("outputs", {})) if rec else {}

    def running_hash(self, stage: str) -> str | None:
        p = self.running_path(stage)
        try:
            return json.loads(p.read_text()).get("input_hash") if p.is_file() else None
        except json.JSONDecodeError:
            return None

    def start(self, stage: str, input_hash: str) -> None:
        """Forget any completion record and note that `stage` runs with `input_hash`."""
        self.done_path(stage).unlink(missing_ok=True)
        write_json_atomic(self.running_path(stage), {"input_hash": input_hash, "started": time.time()})

    def finish(self, stage: str, input_hash: str, outputs: list[str], seconds: float, extra: dict | None = None,
               ) -> dict:
        """Record completion: output files (relative to the run folder) with their hashes, wall time (s)."""
        rec = {"stage": stage, "input_hash": input_hash,
               "outputs": {rel: file_sha256(self.run_dir / rel) for rel in outputs},
               "seconds": round(float(seconds), 3), "finished": time.time(), **(extra or {})}
        write_json_atomic(self.done_path(stage), rec)
        self.running_path(stage).unlink(missing_ok=True)
        return rec
