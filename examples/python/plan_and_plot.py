"""Register the demo case, plan it, and save a figure of the zones and layers.

    python examples/python/plan_and_plot.py [--out zones.png] [--seed 1]

Needs matplotlib (``pip install matplotlib``) and the trimctl package
(``pip install ./crates/pybind``).
"""

import argparse
import sys

import numpy as np

import trimctl


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="zones.png", help="figure file (PNG, SVG or PDF)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the demo part")
    ap.add_argument("--scan-points", type=int, default=200_000, help="points in the demo scan")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    case = trimctl.synth(seed=args.seed, scan_points=args.scan_points, cad_points=args.scan_points)
    reg = trimctl.register_path(
        case.cad_points,
        case.scan,
        case.path,
        cad_normals=case.cad_normals,
        init=case.scan_from_cad_nominal,
        settings={"cad_sample_points": args.scan_points},
    )
    err_um = 1e3 * np.linalg.norm(reg.path.points - case.truth.points, axis=1)
    print(f"registration: {len(reg.path)} contours, pointwise error P95 {np.percentile(err_um, 95):.1f} µm, "
          f"max {err_um.max():.1f} µm, untrustworthy {reg.untrustworthy}")

    plan = trimctl.plan(reg.path, max_incidence_deg=5.0)
    zones = plan.zones
    print(f"plan: {len(zones)} zones (k = {plan.k}), ΔH = {plan.layer_step_mm:.3f} mm, "
          f"estimate {plan.estimate['total_s']:.1f} s, validation "
          f"{'passed' if plan.validation['passed'] else 'FAILED'}")

    fig = plt.figure(figsize=(14, 8))
    top = fig.add_subplot(1, 2, 1)
    cmap = plt.get_cmap("tab20")
    colour = {}
    for z in zones:
        for cid in z.contours:
            colour[cid] = cmap(z.id % 20)
    sub = case.scan[:: max(1, len(case.scan) // 20000)]
    top.scatter(sub[:, 0], sub[:, 1], s=0.2, c="0.8", label="scan")
    for cid in reg.path.contour_ids:
        pts, _ = reg.path.contour(cid)
        top.plot(pts[:, 0], pts[:, 1], color=colour.get(cid, "k"), lw=1.2)
    for z in zones:
        top.annotate(str(z.id), z.origin[:2], fontsize=7, ha="center")
    top.set_aspect("equal")
    top.set_title("zones over the part (top view, scan frame, mm)")
    top.set_xlabel("x (mm)")
    top.set_ylabel("y (mm)")

    # The busiest zones' layers in galvo millimetres.
    busiest = sorted(zones, key=lambda z: -sum(len(l.polylines) for l in z.layers))[:4]
    for i, z in enumerate(busiest):
        ax = fig.add_subplot(4, 2, 2 * i + 2)
        for layer in z.layers:
            for _, xy in layer.polylines:
                ax.plot(xy[:, 0], xy[:, 1], lw=1.0, label=f"layer {layer.index}")
        ax.set_aspect("equal")
        ax.set_title(f"zone {z.id}: {len(z.layers)} layer(s), incidence ≤ {z.max_incidence_deg:.2f}°",
                     fontsize=9)
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
