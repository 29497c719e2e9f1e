"""Point probes: temperature and velocity at fixed points over time, the form a user sets
against a thermocouple or an IR camera. Values are kernel-weighted (Shepard) averages of the
particles within one support radius, which reproduce a constant field exactly and a linear
one at points with a symmetric neighbourhood (a lattice node or cell centre)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

COLUMNS = ["time_s", "probe", "x_mm", "y_mm", "z_mm", "particles", "temperature_c",
           "vx_m_s", "vy_m_s", "vz_m_s", "speed_m_s"]


def shepard(points_m: np.ndarray, positions_m: np.ndarray, values: np.ndarray, weight, support_m: float):
    """(value at each point, particles within the support); rows with no particle nearby are
    NaN with a count of 0 (reported as blanks, never as numbers)."""
    values = np.asarray(values, dtype=np.float64)
    out = np.full((len(points_m),) + values.shape[1:], np.nan)
    counts = np.zeros(len(points_m), dtype=int)
    for k, p in enumerate(np.asarray(points_m, dtype=np.float64)):
        d = np.linalg.norm(positions_m - p, axis=1)
        near = d < support_m
        w = weight(d[near])
        counts[k] = int(near.sum())
        if counts[k] and w.sum() > 0:
            out[k] = np.tensordot(w, values[near], axes=1) / w.sum()
    return out, counts


class ProbeRecorder:
    """Samples the probes of a run; ``write`` leaves probes.csv and probes.png."""

    def __init__(self, points_mm, weight, support_m: float):
        self.points_m = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3) * 1e-3
        self.weight = weight
        self.support_m = support_m
        self.rows: list[dict] = []

    def sample(self, time_s: float, positions_m, velocity_m_s, temperature_c=None) -> None:
        v, counts = shepard(self.points_m, positions_m, velocity_m_s, self.weight, self.support_m)
        temp = None
        if temperature_c is not None:
            temp, _ = shepard(self.points_m, positions_m, temperature_c, self.weight, self.support_m)
        for k, p in enumerate(self.points_m * 1e3):
            row = {"time_s": float(time_s), "probe": k, "x_mm": p[0], "y_mm": p[1], "z_mm": p[2],
                   "particles": int(counts[k])}
            if counts[k]:
                row.update(vx_m_s=v[k, 0], vy_m_s=v[k, 1], vz_m_s=v[k, 2],
                           speed_m_s=float(np.linalg.norm(v[k])))
                if temp is not None:
                    row["temperature_c"] = float(temp[k])
            self.rows.append(row)

    def write(self, out_dir) -> list[Path]:
        out_dir = Path(out_dir)
        path = out_dir / "probes.csv"
        with path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            for row in self.rows:
                w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in COLUMNS})
        return [path, self._plot(out_dir / "probes.png")]

    def _plot(self, path: Path) -> Path:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        has_t = any("temperature_c" in r for r in self.rows)
        fig, axes = plt.subplots(2 if has_t else 1, 1, figsize=(7, 5.5 if has_t else 3.2),
                                 sharex=True, squeeze=False)
        for k, p in enumerate(self.points_m * 1e3):
            rows = [r for r in self.rows if r["probe"] == k]
            t = [r["time_s"] for r in rows]
            label = f"probe {k}: ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) mm"
            speed = [r.get("speed_m_s", np.nan) * 1e3 for r in rows]
            axes[-1, 0].plot(t, speed, label=label)
            if has_t:
                axes[0, 0].plot(t, [r.get("temperature_c", np.nan) for r in rows], label=label)
        axes[-1, 0].set_ylabel("speed [mm/s]")
        axes[-1, 0].set_xlabel("time [s]")
        if has_t:
            axes[0, 0].set_ylabel("temperature [degC]")
        axes[0, 0].legend(fontsize=7)
        axes[0, 0].set_title("probes (blank where no particle is within one support radius)",
                             fontsize=9)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return path
