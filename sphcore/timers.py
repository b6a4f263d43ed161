"""Per-stage wall-clock timing of the step, summarised as in seed 001's profiling table
(mean, median and standard deviation per stage)."""
import time
from contextlib import contextmanager

import numpy as np


class StageTimers:
    def __init__(self):
        self.samples: dict[str, list[float]] = {}
        self.enabled = True

    @contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            if self.enabled:
                self.samples.setdefault(name, []).append(time.perf_counter() - t0)

    def reset(self):
        self.samples.clear()

    def summary(self) -> dict:
        """{stage: {total_s, mean_s, median_s, std_s, calls}} in the order stages first ran."""
        out = {}
        for name, vals in self.samples.items():
            a = np.asarray(vals)
            out[name] = {"total_s": float(a.sum()), "mean_s": float(a.mean()), "median_s": float(np.median(a)),
                         "std_s": float(a.std()), "calls": int(a.size)}
        return out
