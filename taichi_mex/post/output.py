"""HDF5 frames (h5py) with an XDMF sidecar, so ParaView opens a run directly.

Layout of ``particles.h5``::

    /               attrs: config (JSON), units (JSON), scene, taichi_mex version
    /plate/position static boundary particles (m)
    /frames/000042  attrs: time_s, step; datasets: position, velocity, density, pressure,
                    bead_id, phase, and temperature when the scene carries heat

Each frame holds the melt (fluid and solidified) and the moving nozzle/inlet particles.
The file is flushed after every frame, so an interrupted run keeps what was written.
"""

import json
from pathlib import Path

import h5py
import numpy as np

UNITS = {
    "position": "m", "velocity": "m/s", "density": "kg/m^3", "pressure": "Pa",
    "temperature": "degC", "bead_id": "1", "phase": "0 fluid, 1 solid, 2 plate, 3 nozzle, 4 inlet",
    "viscosity": "Pa s", "surface_area": "m^2",
}


class FrameWriter:
    def __init__(self, out_dir: Path, config: dict, scene: str, fields: list[str],
                 resume_at_s: float | None = None):
        """``resume_at_s``: append to the run's file, dropping frames written after that time
        (a frame the run wrote after its last checkpoint)."""
        from taichi_mex import __version__

        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.path = self.out_dir / "particles.h5"
        self.fields = fields
        if resume_at_s is not None:
            self.h5 = h5py.File(self.path, "a")
            self.frames = self.h5.require_group("frames")
            self.index = []
            for name in sorted(self.frames):
                g = self.frames[name]
                if g.attrs["time_s"] > resume_at_s + 1e-12:
                    del self.frames[name]
                else:
                    self.index.append((name, float(g.attrs["time_s"]), len(g["position"])))
            return
        self.h5 = h5py.File(self.path, "w")
        self.h5.attrs["config"] = json.dumps(config, default=str)
        self.h5.attrs["units"] = json.dumps({k: UNITS.get(k, "") for k in ["position"] + fields})
        self.h5.attrs["scene"] = scene
        self.h5.attrs["taichi_mex_version"] = __version__
        self.frames = self.h5.create_group("frames")
        self.index: list[tuple[str, float, int]] = []

    def write_plate(self, position_m: np.ndarray) -> None:
        g = self.h5.require_group("plate")
        g.create_dataset("position", data=position_m, compression="gzip", compression_opts=1)
        g.attrs["units"] = "m"

    def write_frame(self, time_s: float, step: int, data: dict[str, np.ndarray]) -> str:
        name = f"{len(self.index):06d}"
        g = self.frames.create_group(name)
        g.attrs["time_s"] = float(time_s)
        g.attrs["step"] = int(step)
        for key, value in data.items():
            g.create_dataset(key, data=value, compression="gzip", compression_opts=1)
            g[key].attrs["units"] = UNITS.get(key, "")
        self.index.append((name, float(time_s), len(data["position"])))
        self.h5.flush()
        self._write_xdmf()
        return name

    def _write_xdmf(self) -> None:
        h5name = self.path.name
        grids = []
        for name, time_s, n in self.index:
            g = self.frames[name]
            attrs = []
            for key in g.keys():
                if key == "position":
                    continue
                ds = g[key]
                kind = "Vector" if ds.ndim == 2 else "Scalar"
                dims = f"{n} 3" if ds.ndim == 2 else f"{n}"
                num = "Int" if ds.dtype.kind in "iu" else "Float"
                prec = ds.dtype.itemsize
                attrs.append(
                    f'        <Attribute Name="{key}" AttributeType="{kind}" Center="Node">\n'
                    f'          <DataItem Dimensions="{dims}" NumberType="{num}" Precision="{prec}" '
                    f'Format="HDF">{h5name}:/frames/{name}/{key}</DataItem>\n        </Attribute>')
            prec = g["position"].dtype.itemsize
            grids.append(
                f'      <Grid Name="frame{name}" GridType="Uniform">\n'
                f'        <Time Value="{time_s:.9g}"/>\n'
                f'        <Topology TopologyType="Polyvertex" NumberOfElements="{n}"/>\n'
                f'        <Geometry GeometryType="XYZ">\n'
                f'          <DataItem Dimensions="{n} 3" NumberType="Float" Precision="{prec}" '
                f'Format="HDF">{h5name}:/frames/{name}/position</DataItem>\n        </Geometry>\n'
                + "\n".join(attrs) + "\n      </Grid>")
        text = ('<?xml version="1.0" ?>\n<Xdmf Version="3.0">\n  <Domain>\n'
                '    <Grid Name="particles" GridType="Collection" CollectionType="Temporal">\n'
                + "\n".join(grids) + "\n    </Grid>\n  </Domain>\n</Xdmf>\n")
        (self.out_dir / "particles.xdmf").write_text(text)

    def close(self) -> None:
        if self.h5:
            self.h5.close()
            self.h5 = None


def read_frames(path) -> list[dict]:
    """All frames of a particles.h5 as dicts of numpy arrays (plus 'time_s')."""
    out = []
    with h5py.File(path, "r") as h5:
        for name in sorted(h5["frames"].keys()):
            g = h5["frames"][name]
            d = {k: g[k][()] for k in g.keys()}
            d["time_s"] = float(g.attrs["time_s"])
            out.append(d)
    return out


def read_json(path):
    """A run file's JSON (summary.json, config.json, ...), or None when it is missing or
    unreadable (a run stopped before writing it)."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def read_config(path) -> dict:
    with h5py.File(path, "r") as h5:
        return json.loads(h5.attrs["config"])
