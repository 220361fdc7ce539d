"""Long fuzz sweep of the readers users feed the runtime (issues 18 and 31): mutated DNG/TIFF/JPEG/PNG frames
(metadata and pixels), maker-note blocks, capture.json, gt.json, and whole random capture folders through
`aat-infer --method focus`. Prints a table: cases, clean errors (the project's own CaptureError; for capture folders
exit status 1 with one line naming a file in the folder), other exceptions (bugs; for capture folders also any
broken promise: inputs changed, a temporary left behind, a message that names no file, an unexpected exception),
crashes (the worker process died) and hangs (no answer within --timeout).

    python tests/fuzz_readers.py [--cases 1000] [--seed 0] [--timeout 10] [--readers frame,capture_folder,...]

Each case runs in a worker subprocess (restarted after a crash or hang), so a segfault in a decoder is counted, not
fatal. Seeds: a virtual-camera DNG, a Canon maker-note JPEG and a 16-bit PNG made here, plus the real files in
../shared/data/raw_exif_makernotes_exiftool when present. tests/deploy/test_bad_inputs.py runs the bounded version in CI.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "raw_exif_makernotes_exiftool"
READERS = ("frame", "makernote", "capture_json", "gt_json", "capture_folder")
MAKERS = [b"Canon", b"NIKON", b"OLYMPUS", b"KONICA MINOLTA", b"CASIO"]
NOTE_HEADS = [b"", b"Nikon\0\x02\x10\0\0", b"Nikon\0\x01\0", b"OLYMPUS\0II\x03\0", b"OLYMP\0\x01\0", b"QVC\0\0\0"]
EXTREMES = [0, 1, 0xFFFF, 0x7FFFFFFF, 0xFFFFFFFF, 0x80000000]


# -- worker: run one reader on one case, answer one JSON line -------------------------------------------------------
def run_folder_case(case: Path) -> dict:
    """A random capture folder (case/cap, with case/outside beside it) through aat-infer --method focus, and the
    promises checked: exit status 0 or 1, a failure is one line naming the folder or a file in it, inputs
    byte-identical, no temporary left; a folder with a bad entry (cut, bomb, garbage, NaN, a link out of it or to
    another frame ...) is refused, one of good frames of any format and name, listed in capture.json, runs."""
    import contextlib
    import io

    from deploy_fixtures import GOOD_KINDS, SKIPPED_UNLISTED, tree_hash

    from aat_deploy.cli import infer

    cap, out = case / "cap", case / "o"
    spec = json.loads((case / "spec.json").read_text())  # the entry kinds and sidecar it was made of
    before = tree_hash(cap, case / "outside")
    err, std = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
        rc = infer.main([str(cap), "--method", "focus", "--out", str(out), "-q", "--no-recording"])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip() and "warning:" not in ln]
    broken = []
    if tree_hash(cap, case / "outside") != before:
        broken.append("inputs changed")
    if [q for q in case.rglob(".*") if q.name != ".aat-output.json"]:
        broken.append("temporary left")
    if rc == 1:
        why = lines[0].split(f"FAILED {cap}: ", 1)[-1] if lines else ""
        if "unexpected" in why or "Traceback" in err.getvalue():
            broken.append(why[:100])
        elif not why.startswith(str(cap)):
            broken.append(f"names no file: {why[:80]}")
    elif rc != 0:
        broken.append(f"exit status {rc}")
    kinds, sidecar = set(spec["kinds"]), spec["sidecar"]
    if rc == 0 and not kinds <= GOOD_KINDS | (SKIPPED_UNLISTED if sidecar == "none" else set()):
        broken.append("accepted bad input: " + ", ".join(sorted(kinds - GOOD_KINDS)))
    if rc == 1 and kinds <= GOOD_KINDS and sidecar in ("list", "list_bom") and len(spec["kinds"]) >= 3:
        broken.append("refused a good capture")
    if broken:
        return {"outcome": "other", "detail": "; ".join(broken)}
    return {"outcome": "ok"} if rc == 0 else {"outcome": "clean", "one_line": len(lines) == 2}


def run_case(kind: str, path: str) -> dict:
    from aat_deploy.errors import CaptureError

    p = Path(path)
    if kind == "capture_folder":
        try:
            return run_folder_case(p)
        except Exception as e:  # noqa: BLE001 (the command itself raised: a bug)
            why = str(e).splitlines()[0][:100] if str(e) else ""
            return {"outcome": "other", "detail": f"{type(e).__name__}: {why}"}
    try:
        if kind in ("frame", "makernote"):
            from aat_deploy.capture.exif import read_metadata

            read_metadata(p, use_exiftool=False)
            if kind == "frame":
                from aat_deploy.capture.raw import load_frame

                load_frame(p)
        elif kind == "capture_json":
            from aat_deploy.capture.folder import read_capture

            read_capture(p, use_exiftool=False)
        else:
            from aat_deploy.gt.read import find_gt, load_ground_truth

            src = find_gt(p)
            if src is not None:
                load_ground_truth(src)
    except CaptureError as e:
        return {"outcome": "clean", "one_line": "\n" not in str(e)}
    except Exception as e:  # noqa: BLE001 (this is what the sweep counts)
        return {"outcome": "other", "detail": f"{type(e).__name__}: {str(e).splitlines()[0][:100] if str(e) else ''}"}
    return {"outcome": "ok"}


def worker() -> None:
    for line in sys.stdin:
        req = json.loads(line)
        print(json.dumps(run_case(req["kind"], req["path"])), flush=True)


class Worker:
    """A worker subprocess; ask() returns its answer, or "crash" / "hang" (and restarts it)."""

    def __init__(self):
        self.proc = None
        self.start()

    def start(self):
        env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
        self.proc = subprocess.Popen([sys.executable, __file__, "--worker"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)

    def ask(self, kind: str, path: Path, timeout: float) -> dict:
        try:
            self.proc.stdin.write(json.dumps({"kind": kind, "path": str(path)}) + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            self.start()
            return {"outcome": "crash", "detail": "worker gone"}
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.proc.kill()
            self.proc.wait()
            self.start()
            return {"outcome": "hang", "detail": f"no answer in {timeout:g} s"}
        line = self.proc.stdout.readline()
        if not line:
            rc = self.proc.wait()
            self.start()
            return {"outcome": "crash", "detail": f"worker exited with {rc}"}
        return json.loads(line)

    def close(self):
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


# -- case makers ----------------------------------------------------------------------------------------------------
def mutate(buf: bytes, rng: np.random.Generator) -> bytes:
    """One of: random byte flips, flips in the first 512 bytes (headers, IFDs), 32-bit words set to extreme
    values (offsets, counts), truncation, inserted random bytes."""
    b = bytearray(buf)
    op = rng.integers(5)
    if op == 0:
        for _ in range(rng.integers(1, 17)):
            b[rng.integers(len(b))] = rng.integers(256)
    elif op == 1:
        for _ in range(rng.integers(1, 9)):
            b[rng.integers(min(512, len(b)))] = rng.integers(256)
    elif op == 2 and len(b) >= 4:  # (a shorter buffer has no 32-bit word)
        for _ in range(rng.integers(1, 5)):
            at = int(rng.integers(max(1, min(1024, len(b)) - 4)))
            struct.pack_into("<I" if rng.integers(2) else ">I", b, at, int(rng.choice(EXTREMES)))
    elif op == 3:
        b = b[: rng.integers(len(b))]
    else:
        at = rng.integers(len(b))
        b[at:at] = rng.integers(0, 256, rng.integers(1, 64), dtype=np.uint8).tobytes()
    return bytes(b)


def random_json(rng: np.random.Generator, depth: int = 0):
    r = rng.integers(9 if depth < 3 else 6)
    if r == 0:
        return None
    if r == 1:
        return bool(rng.integers(2))
    if r == 2:
        return float(rng.choice([0.0, -1.0, 0.6, 1e308, float("nan"), float("inf"), 4e9, rng.normal()]))
    if r == 3:
        return int(rng.choice([0, 1, -5, 10**30])) if rng.integers(4) else 10**400
    if r == 4:
        return str(rng.choice(["img_0.png", "../img_0.png", "/etc/hostname", "raw/x.png", "", "a\0b", "C:\\x.png",
                               "img_1.png/", "nope.png", "gt_depth_m.npy", "gt_mask.png"]))
    if r == 5:
        return "x" * int(rng.integers(0, 20))
    if r in (6, 7):
        return [random_json(rng, depth + 1) for _ in range(rng.integers(0, 4))]
    keys = ["frames", "file", "focus_m", "depth", "scale_to_m", "mask", "note", "x"]
    return {str(rng.choice(keys)): random_json(rng, depth + 1) for _ in range(rng.integers(0, 4))}


def sidecar_doc(rng: np.random.Generator) -> bytes:
    if rng.integers(4) == 0:
        return json.dumps(random_json(rng)).encode()
    frames = []
    for i in range(rng.integers(0, 4)):
        fr = {"file": f"img_{i % 2}.png", "focus_m": 0.6 + i}
        for k in ("file", "focus_m"):
            if rng.integers(3) == 0:
                fr[k] = random_json(rng, 2)
        frames.append(fr)
    text = json.dumps({"frames": frames}).encode()
    return mutate(text, rng) if rng.integers(4) == 0 else text


def gt_doc(rng: np.random.Generator) -> bytes:
    if rng.integers(4) == 0:
        return json.dumps(random_json(rng)).encode()
    doc = {}
    for k, good in (("depth", "gt_d.pfm"), ("scale_to_m", 1.0), ("mask", "gt_mask.png")):
        c = rng.integers(3)
        if c == 1:
            doc[k] = good
        elif c == 2:
            doc[k] = random_json(rng, 2)
    text = json.dumps(doc).encode()
    return mutate(text, rng) if rng.integers(4) == 0 else text


def makernote_jpeg(base: bytes, rng: np.random.Generator) -> bytes:
    """The Canon test JPEG with its maker note replaced by a maker's header + random bytes, Make changed."""
    jpg = bytearray(base)
    entry = jpg.index(struct.pack("<H", 0x927C))
    tiff_at = jpg.index(b"II*\0")
    block = bytes(NOTE_HEADS[rng.integers(len(NOTE_HEADS))]) + rng.integers(0, 256, rng.integers(0, 400),
                                                                              dtype=np.uint8).tobytes()
    struct.pack_into("<I", jpg, entry + 4, len(block))
    struct.pack_into("<I", jpg, entry + 8, len(jpg) - 2 - tiff_at)
    body = bytes(jpg[:-2]).replace(b"Canon\0", MAKERS[rng.integers(len(MAKERS))][:5] + b"\0", 1) + block
    body += b"\xff\xd9"
    return body[:4] + struct.pack(">H", len(body) - 6) + body[6:]


def seeds(tmp: Path) -> dict[str, bytes]:
    from deploy_fixtures import canon_jpeg, fuzz_seeds, write_dng_capture, write_png_capture

    cap = write_dng_capture(tmp / "seed_dng", [0.7, 1.4], h=24, w=32, gt=False)
    png = write_png_capture(tmp / "seed_png", [0.7, 1.4], h=24, w=32)
    out = {"virtual.dng": (cap / "frame_00.dng").read_bytes(), "canon.jpg": canon_jpeg(216, 0),
           "frame.png": (png / "img_0.png").read_bytes()}
    FOLDER_SEEDS.update(fuzz_seeds(tmp / "folder_seeds"))
    if SHARED.is_dir():
        out.update({p.name: p.read_bytes() for p in sorted(SHARED.iterdir()) if p.suffix != ".md"})
    return out


FOLDER_SEEDS: dict[str, list[bytes]] = {}  # good frames for random capture folders (filled by seeds())


def make_case(kind: str, i: int, rng: np.random.Generator, base: dict[str, bytes], tmp: Path) -> Path:
    d = tmp / f"{kind}_{i}"
    if kind == "capture_folder":  # 3..6 good frames of any format and name, in 60 % of the cases 1 or 2 of them
        from deploy_fixtures import ENTRY_KINDS, SIDECAR_KINDS, random_capture  # replaced by any entry kind

        kinds = [str(rng.choice(["jpeg", "png", "dng", "jpeg_named_png"])) for _ in range(rng.integers(3, 7))]
        if rng.random() < 0.6:
            for at in rng.choice(len(kinds), size=rng.integers(1, 3), replace=False):
                kinds[at] = str(rng.choice(ENTRY_KINDS))
        sidecar = str(rng.choice(SIDECAR_KINDS)) if rng.random() < 0.3 else "list"
        junk = rng.integers(0, 256, rng.integers(1, 64), dtype=np.uint8).tobytes()
        kinds = random_capture(d / "cap", kinds, sidecar, FOLDER_SEEDS, d / "outside", junk)
        (d / "spec.json").write_text(json.dumps({"kinds": kinds, "sidecar": sidecar}))
        return d
    d.mkdir()
    if kind == "frame":
        name = list(base)[rng.integers(len(base))]
        f = d / ("f" + Path(name).suffix.lower())
        f.write_bytes(mutate(base[name], rng))
        return f
    if kind == "makernote":
        f = d / "mn.jpg"
        f.write_bytes(makernote_jpeg(base["canon.jpg"], rng))
        return f
    if kind == "capture_json":
        for j in range(2):
            (d / f"img_{j}.png").write_bytes(base["frame.png"])
        (d / "capture.json").write_bytes(sidecar_doc(rng))
        return d
    np.save(d / "gt_depth_m.npy", np.full((6, 8), 1.5, np.float32))
    if rng.integers(3) == 0:
        (d / "gt_depth_m.npy").write_bytes(mutate((d / "gt_depth_m.npy").read_bytes(), rng))
    pfm = b"Pf\n8 6\n-1\n" + np.full(48, 1.5, "<f4").tobytes()
    (d / "gt_d.pfm").write_bytes(mutate(pfm, rng) if rng.integers(2) else pfm)
    (d / "gt.json").write_bytes(gt_doc(rng))
    return d


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=1000, help="cases per reader")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--readers", default=",".join(READERS),
                    help=f"comma-separated subset of {','.join(READERS)} (each reader's cases depend only on the seed)")
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds before a case counts as a hang")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker()
        return 0
    readers = [r for r in args.readers.split(",") if r]
    unknown = sorted(set(readers) - set(READERS))
    if unknown:
        ap.error(f"--readers: unknown {', '.join(unknown)}")
    t0 = time.perf_counter()
    rows, others = [], Counter()
    with tempfile.TemporaryDirectory(prefix="aat_fuzz_") as tmp:
        tmp = Path(tmp)
        base = seeds(tmp)
        w = Worker()
        try:
            for kind in readers:
                rng = np.random.default_rng([args.seed, READERS.index(kind)])
                count, multi = Counter(), 0
                for i in range(args.cases):
                    res = w.ask(kind, make_case(kind, i, rng, base, tmp), args.timeout)
                    count[res["outcome"]] += 1
                    multi += res.get("one_line") is False
                    if res["outcome"] in ("other", "crash", "hang"):
                        others[(kind, res["outcome"], res.get("detail", ""))] += 1
                    if i % 250 == 249:
                        print(f"  {kind}: {i + 1}/{args.cases}", file=sys.stderr, flush=True)
                rows.append((kind, args.cases, count["ok"], count["clean"], count["other"], count["crash"],
                             count["hang"], multi))
        finally:
            w.close()
    print(f"seeds: {len(base)} files ({'with' if SHARED.is_dir() else 'without'} ../shared samples); "
          f"seed {args.seed}; {time.perf_counter() - t0:.0f} s")
    print("| reader | cases | read fine | clean errors | other exceptions | crashes | hangs | multi-line errors |")
    print("|---|---|---|---|---|---|---|---|")
    tot = [0] * 7
    for r in rows:
        print("| " + " | ".join(str(v) for v in r) + " |")
        tot = [a + b for a, b in zip(tot, r[1:])]
    print("| **all** | " + " | ".join(str(v) for v in tot) + " |")
    for (kind, outcome, detail), n in others.most_common():
        print(f"{kind} {outcome} x{n}: {detail}")
    return 1 if others else 0


if __name__ == "__main__":
    sys.exit(main())
