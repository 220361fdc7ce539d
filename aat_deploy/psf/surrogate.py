"""Query an exported PSF surrogate with onnxruntime (no torch)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnxruntime as ort

from ..machine import bound_threads


class PSFSurrogate:
    """An ONNX PSF surrogate and its metadata (lens, sensor, kernel size, valid ranges, units)."""

    def __init__(self, path, threads: int | None = None):
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such PSF model")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = bound_threads(threads)
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own exception types
            raise ValueError(f"{path}: not a loadable ONNX model ({e})") from None
        self.meta = dict(self.session.get_modelmeta().custom_metadata_map)
        if self.meta.get("aat.kind") != "psf_surrogate":
            raise ValueError(f"{path}: not an aat PSF surrogate (metadata aat.kind = {self.meta.get('aat.kind')!r})")
        self.path = path
        self.kernel_size = int(self.meta["aat.kernel_size"])
        self.depth_range_m = tuple(json.loads(self.meta["aat.depth_range_m"]))
        self.focus_range_m = tuple(json.loads(self.meta["aat.focus_range_m"]))
        self.lens_hash = self.meta["aat.lens_hash"]

    def query(self, x, y, depth_m, focus_m, batch: int = 65536) -> tuple[np.ndarray, np.ndarray]:
        """Kernels (N, k, k) and cell sizes in pixels (N,) for arrays that broadcast together."""
        x, y, d, f = (np.asarray(a, dtype=np.float32).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        for name, v, (lo, hi) in (("depth_m", d, self.depth_range_m), ("focus_m", f, self.focus_range_m)):
            if v.size and (v.min() < lo * (1 - 1e-6) or v.max() > hi * (1 + 1e-6)):
                raise ValueError(f"{self.path}: {name} outside the model's valid range {lo}..{hi} m "
                                 f"(got {v.min():.3g}..{v.max():.3g})")
        q = np.stack([x, y, d, f], -1)
        ks, ss = [], []
        for i in range(0, q.shape[0], batch):
            k, s = self.session.run(None, {"query": q[i:i + batch]})
            ks.append(k)
            ss.append(s)
        if not ks:
            k = self.kernel_size
            return np.zeros((0, k, k), np.float32), np.zeros(0, np.float32)
        return np.concatenate(ks), np.concatenate(ss)
