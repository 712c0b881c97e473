"""Simulator figures: central bias, temporal std, corner deformation at 1-4 m; timing."""
import time, tempfile, numpy as np
from pathlib import Path
from tofmetry._shared.geometry import fit_plane_svd
from tofmetry.simulate import VirtualKinect, ErrorModel, scenes
from tofmetry.simulate.datasets import write_frames
from tofmetry.io import CaptureMeta
from tofmetry.sensor import KINECT_V2

intr = KINECT_V2.depth
xy = np.asarray(intr.ray_table())
C = (slice(202, 212), slice(251, 261))
corners = {"TL": (slice(0, 10), slice(0, 10)), "TR": (slice(0, 10), slice(-10, None)),
           "BL": (slice(-10, None), slice(0, 10)), "BR": (slice(-10, None), slice(-10, None))}
print("dist_m  centre_bias_mm  centre_std_mm  corner_minus_centre_after_planefit_mm (TL TR BL BR)")
for d in (1.0, 2.0, 3.0, 4.0):
    vk = VirtualKinect(ErrorModel(), seed=0)
    fr = vk.capture(scenes.wall(d), n_frames=50)
    D = fr.depth.astype(float)
    valid = D > 0
    cnt = valid.sum(0)
    mean = np.where(cnt > 0, D.sum(0) / np.maximum(cnt, 1), 0)
    cb = D[:, C[0], C[1]][valid[:, C[0], C[1]]].mean() - d * 1000
    std = np.array([D[valid[:, v, u], v, u].std(ddof=1) for v in range(202, 212) for u in range(251, 261)]).mean()
    ok = cnt >= 25
    z = mean[ok] * 1e-3
    P = np.column_stack([xy[..., 0][ok] * z, xy[..., 1][ok] * z, z])
    plane = fit_plane_svd(P, orient=(0.0, 0.0, 1.0))
    res = np.full(mean.shape, np.nan)
    res[ok] = (P @ plane[:3] + plane[3]) * 1000  # + = farther than the fitted plane
    rc = np.nanmean(res[C])
    cd = [np.nanmean(res[s]) - rc for s in corners.values()]
    print(f"{d:4.1f}  {cb:+8.2f}  {std:6.2f}  " + " ".join(f"{x:+7.1f}" for x in cd), f"  valid={valid.mean():.3f}")

vk = VirtualKinect(ErrorModel(), seed=0)
sc = scenes.wall(1.0)
t = time.perf_counter(); fr = vk.capture(sc, n_frames=50); t1 = time.perf_counter() - t
with tempfile.TemporaryDirectory() as tmp:
    t = time.perf_counter()
    write_frames(Path(tmp) / "cap", vk.iter_frames(sc, 50), CaptureMeta(sensor="kinect_v2"))
    t2 = time.perf_counter() - t
print(f"simulate 50 wall frames (render + frames, in memory): {t1:.2f} s; simulate + write as a capture (depth+IR PNG): {t2:.2f} s")
