"""Run the chain in one folder: refuse a folder made with other settings (unless force), skip up-to-date stages,
resume or restart the others, and coordinate torchrun processes.

Under torchrun (WORLD_SIZE > 1) the process group is created here (NCCL on GPUs, gloo on CPUs:
training.devices.distributed), with a long timeout: the PSF fit may take longer than the default while the other
processes wait. Rank 0 decides every stage and runs the
non-distributed ones; the training stages run on every process (the loop shards the data and writes files from
rank 0 only); decisions and failures are broadcast so all processes agree. With several machines the run folder
must be on a shared filesystem.
"""

from __future__ import annotations

import datetime
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from aat_deploy.errors import AatError
from training.chain import config as chain_config
from training.chain.hashing import StageMarkers, dict_sha256, write_json_atomic
from training.chain.stages import Context, Stage, stages

DIST_TIMEOUT = datetime.timedelta(hours=12)


class ChainError(AatError, RuntimeError):
    """A run that cannot go on (one line)."""


@dataclass
class ChainResult:
    """What happened to each stage: "skipped" (up to date), "ran" or "resumed"; wall times (s) of the stages run."""

    run_dir: Path
    actions: dict[str, str] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)


def input_hash(stage: Stage, ctx: Context, markers: StageMarkers, producers: dict[str, str]) -> str:
    """SHA-256 of the stage's settings and the recorded hashes of the files it reads."""
    reads = {}
    for rel in stage.reads(ctx):
        rec = markers.output_hashes(producers[rel]) if rel in producers else {}
        if rel not in rec:
            raise ChainError(f"stage {stage.name}: input {rel} has no completed record")
        reads[rel] = rec[rel]
    return dict_sha256({"stage": stage.name, "settings": stage.settings(ctx), "reads": reads})


def _producers(ctx: Context) -> dict[str, str]:
    """Which stage writes each run-folder file a later stage reads."""
    out = {"lens.json": "lens", "lens_report.json": "lens", "psf.onnx": "psf",
           "metrics.json": "evaluate", "error_vs_radius.png": "evaluate", "error_over_field.png": "evaluate"}
    from training.chain.stages import _colour_files, onnx_name, train_dir

    out.update({f: "psf_colour" for f in _colour_files(ctx)})
    for s in ctx.simulators:
        out[f"{train_dir(s)}/model.pt"] = train_dir(s)
        out[onnx_name(ctx, s)] = "export"
    return out


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()


def check_config(run_dir: Path, cfg: dict, force: bool) -> list[str]:
    """Compare with DIR/config.json. Different settings are refused unless force (then the changed stages rerun).
    Returns the differing keys (empty for a new folder or the same command)."""
    old = chain_config.load(run_dir / "config.json")
    if old is None:
        if run_dir.exists() and any(run_dir.iterdir()) and not (run_dir / "stages").is_dir():
            raise ChainError(f"{run_dir}: exists and is not an aat-train --lens run folder; choose another --out")
        return []
    diff = chain_config.differences(old, cfg)
    if diff and not force:
        raise ChainError(f"{run_dir}: was made with other settings ({', '.join(diff[:6])}"
                         f"{', ...' if len(diff) > 6 else ''} differ); pass --force to retrain what they change "
                         "or choose another --out")
    return diff


def _share(obj, world: int):
    """rank 0's `obj` on every process (torch imported only when there are several)."""
    if world == 1:
        return obj
    from training.devices.distributed import share

    return share(obj, world)


def run_chain(cfg: dict, run_dir, *, force: bool = False, progress: bool = True, log=print,
              stop_after: str | None = None, device: str = "auto", amp: str | None = None) -> ChainResult:
    """Run (or continue) the chain for the resolved config `cfg` in `run_dir`. stop_after: a stage name to stop
    after (tests, benchmarks). device, amp: where torch runs (training.devices). Raises ChainError / the stage's
    exception on failure."""
    from training.devices.distributed import init_distributed
    from training.devices.select import resolve_device

    run_dir = Path(run_dir).resolve()
    rank, world, created = init_distributed(resolve_device(device), DIST_TIMEOUT)
    say = log if rank == 0 else (lambda *_: None)
    try:
        status = None
        if rank == 0:
            try:
                diff = check_config(run_dir, cfg, force)
                run_dir.mkdir(parents=True, exist_ok=True)
                write_json_atomic(run_dir / "config.json", cfg)
                if diff:
                    say(f"settings changed ({', '.join(diff)}): the stages they feed will rerun")
            except (ChainError, OSError) as e:
                status = str(e)
        status = _share(status, world)
        if status:
            raise ChainError(status)
        ctx = Context(run_dir, cfg, rank, world, progress, say, device, amp)
        return _run_stages(ctx, stop_after)
    finally:
        if created:
            import torch.distributed as dist

            dist.destroy_process_group()


def _run_stages(ctx: Context, stop_after: str | None) -> ChainResult:
    markers = StageMarkers(ctx.run_dir)
    producers = _producers(ctx)
    res = ChainResult(ctx.run_dir)
    chain = stages(ctx)
    for i, st in enumerate(chain, 1):
        tag = f"[{i}/{len(chain)}] {st.name}"
        decision = None
        if ctx.rank == 0:
            h = input_hash(st, ctx, markers, producers)
            if markers.up_to_date(st.name, h):
                decision = ("skipped", h)
            else:
                resumed = markers.running_hash(st.name) == h
                if not resumed:
                    for rel in st.work(ctx):
                        _remove(ctx.path(rel))
                markers.start(st.name, h)
                decision = ("resumed" if resumed else "ran", h)
        action, h = _share(decision, ctx.world)
        res.actions[st.name] = action
        if action == "skipped":
            ctx.log(f"{tag}: up to date")
            continue
        ctx.log(f"{tag}: {'resuming' if action == 'resumed' else 'running'}")
        t0 = time.perf_counter()
        failure = None
        outputs: list[str] = []
        if st.distributed or ctx.rank == 0:
            try:
                outputs = st.run(ctx)
            except Exception as e:  # noqa: BLE001 (reported to every process, then re-raised)
                failure = e
        if not st.distributed:
            failure_msg = _share(None if failure is None else f"{type(failure).__name__}: {failure}", ctx.world)
            if failure is None and failure_msg:
                raise ChainError(f"{tag}: failed on rank 0 ({failure_msg})")
        if failure is not None:
            raise failure
        if ctx.rank == 0:
            secs = time.perf_counter() - t0
            markers.finish(st.name, h, outputs, secs, {"action": action})
            res.seconds[st.name] = secs
            ctx.log(f"{tag}: done in {secs:.1f} s")
        _share(None, ctx.world)  # barrier: the record exists before anyone reads it
        if st.name == stop_after:
            break
    return res
