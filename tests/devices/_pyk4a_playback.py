"""Play an Azure Kinect ``.mkv`` back through ``tofmetry.devices.azure`` (pyk4a) and save what it delivers.

Run in a separate environment with ``numpy<2`` and ``pyk4a-bundle`` (tofmetry's own environment has
numpy 2, which pyk4a-bundle 1.5 cannot load), with the repository on ``PYTHONPATH``::

    python tests/devices/_pyk4a_playback.py RECORDING.mkv OUT_DIR

Writes ``OUT_DIR/depth.npy`` and ``ir.npy`` ((T, H, W) uint16), ``timestamps_s.npy`` and ``info.json``
(the device's ``DeviceInfo``, its intrinsics, the versions used).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def main(mkv: str, out: str) -> None:
    import pyk4a

    from tofmetry.devices import make_device

    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    depth, ir, ts, temps = [], [], [], []
    with make_device("azure", mkv=mkv) as dev:
        info = dev.info
        for f in dev.frames():
            depth.append(f.depth)
            ir.append(f.ir)
            ts.append(f.timestamp_s)
            temps.append(f.temperature_c)
    np.save(out_dir / "depth.npy", np.stack(depth))
    np.save(out_dir / "ir.npy", np.stack(ir))
    np.save(out_dir / "timestamps_s.npy", np.asarray(ts, np.float64))
    d = info.to_dict()
    d["depth_intrinsics"] = info.depth_intrinsics.to_dict()
    d["temperatures"] = temps
    d["versions"] = {"numpy": np.__version__, "pyk4a": getattr(pyk4a, "__version__", "?"),
                     "python": sys.version.split()[0]}
    (out_dir / "info.json").write_text(json.dumps(d, indent=1))


if __name__ == "__main__":
    main(*sys.argv[1:3])
