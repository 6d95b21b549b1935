#!/usr/bin/env python3
"""outside.py -- registration measured on cases from a generator written outside the project.

Run through `benches/outside/run` (it builds trimctl and makes the venv). Per case:

1. the generator (`--generator PATH/gen_core.py`, never part of this repository) writes the case
   (CAD STL, CAM path, scan, truth) into `--work` (kept: a case is generated once);
2. `trimctl register --cad cad.stl --scan scan.ply --path path.csv` registers it, timed as a
   whole process (file reading and writing included);
3. the generator's scorer (`score.py` beside it, `--match curve --json`) gives each contour's
   true errors; this script also measures every registered point's cross-track distance to the
   true contour (its own code) for the P95 over the trusted contours.

Per contour the *true error* is max(curve max, cross max) of the scorer (a strip that slid along
itself shows at its ends in the curve metric). Per case it prints: the cross-track P95 and the
worst true error over the contours trimctl left trusted, the silent misses (trusted, true error
over `--tolerance-um`, 30), the false alarms (flagged, true error under half the tolerance),
the bound coverage (true error <= predicted_max_error_um), the flagged count and the time; then
the totals. A part that registration refuses counts every contour as flagged.

Seed sets (keep tuning and reporting apart): `--set tune` uses seeds 2001..; `--set report`
(the default) seeds 1001..; `--set holdout` seeds 3001.., kept for checking a change once
after it was chosen (on the tune seeds) and reported (on the report seeds). All three have been
run many times, so a change chosen after looking at them is not tested by them: `--set fresh
--first-seed N` (N >= 4001) runs a range never run before, once, as that change's clean check
(DESIGN.md lists the ranges used). Each seed draws its case parameters over the whole range the
generator's README gives (fixture 0-20 deg / 0-20 mm, per-axis scale +-0..2 %, sag 0-0.5 mm,
twist 0-1 deg, noise 8-15 um, 2-4 views, 0-3 dropouts, path spacing 0.05-0.25 mm); every fifth
case takes the hardest corner (20 deg, 20 mm, 2 %, 0.5 mm, 1 deg, 15 um, 2 views).

`--generator own` runs the same sweep on the project's own synthetic core (`trimctl synth`)
instead, scored by this script's own code (the same true error: the largest of every registered
point's distance to the true contour and every true point's distance to the registered one).
Its seeds draw 1-4 views fixed to the machine (tilts seeded), fixture 0-20 deg / 0-20 mm,
per-axis scale +-0..2 % along pressing axes tilted 0-30 deg, sag 0-0.5 mm bent up to 30 deg in
the part's plane, twist 0-1 deg, noise 8-15 um, 0-3 dropouts, path spacing 0.05-0.25 mm, and
burrs on 30 % of the contours, 0.05-0.6 mm high; every fifth case the hardest corner with one
view. Its sets: tune 600.., holdout 640.., report 680.., fresh 800 and above.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def case_params(seed, index, points):
    """The generator's options for one case: drawn from the seed, the hardest corner every fifth."""
    r = np.random.default_rng(seed)
    p = dict(
        seed=seed,
        points=points,
        pose_deg=round(float(r.uniform(0, 20)), 2),
        pose_mm=round(float(r.uniform(0, 20)), 2),
        scale_range=round(float(r.uniform(0, 0.02)), 4),
        sag=round(float(r.uniform(0, 0.5)), 3),
        twist=round(float(r.uniform(0, 1)), 3),
        noise=round(float(r.uniform(0.008, 0.015)), 4),
        cams=int(r.integers(2, 5)),
        dropouts=int(r.integers(0, 4)),
        spacing=round(float(r.choice([0.05, 0.05, 0.1, 0.15, 0.25])), 3),
    )
    if index % 5 == 4:
        p.update(pose_deg=20.0, pose_mm=20.0, scale_range=0.02, sag=0.5, twist=1.0, noise=0.015, cams=2)
    return p


# The own cores' shrinkage changes along the span by up to this much end to end (a pressed core's
# density gradient; `trimctl synth --shrink-gradient`).
OWN_SHRINK_GRADIENT = 0.003


def own_params(seed, index, points):
    """`trimctl synth` options for one own case: drawn from the seed, the hardest corner every fifth."""
    r = np.random.default_rng(seed)
    p = dict(
        seed=seed,
        scan_points=points,
        pose_deg=round(float(r.uniform(0, 20)), 2),
        pose_mm=round(float(r.uniform(0, 20)), 2),
        scale_range=round(float(r.uniform(0, 0.02)), 4),
        pressing_tilt=round(float(r.uniform(0, 30)), 1),
        sag=round(float(r.uniform(0, 0.5)), 3),
        bend_tilt=round(float(r.uniform(0, 30)), 1),
        twist=round(float(r.uniform(0, 1)), 3),
        noise=round(float(r.uniform(0.008, 0.015)), 4),
        views=int(r.integers(1, 5)),
        dropouts=int(r.integers(0, 4)),
        path_spacing=round(float(r.choice([0.05, 0.1, 0.15, 0.25])), 3),
        burrs=0.3,
        burr_height="0.05,0.6",
    )
    # Drawn last, so that the draws above are what they were before it existed.
    p["shrink_gradient"] = round(float(r.uniform(-OWN_SHRINK_GRADIENT, OWN_SHRINK_GRADIENT)), 5)
    if index % 5 == 4:
        p.update(pose_deg=20.0, pose_mm=20.0, scale_range=0.02, pressing_tilt=30.0, sag=0.5,
                 twist=1.0, noise=0.015, views=1,
                 shrink_gradient=math.copysign(OWN_SHRINK_GRADIENT, p["shrink_gradient"]))
    return p


def own_meta(case):
    """What run_case needs of an own case (the outside generator's meta.json names)."""
    c = json.load(open(os.path.join(case, "case.json")))
    tc, tp = read_path(os.path.join(case, "truth.csv"))
    burred = {b["contour"] for b in c.get("burrs", [])}
    info = {}
    for i in np.unique(tc):
        q = tp[tc == i]
        step = np.linalg.norm(np.diff(q, axis=0), axis=1)
        closed = bool(len(q) > 2 and np.linalg.norm(q[-1] - q[0]) <= 3 * step.mean())
        info[int(i)] = dict(type="burred" if int(i) in burred else "clean",
                            face="rim" if closed else "strip", closed=closed)
    # The fixture's rotation off the nominal pose (the angle of nominal⁻¹ · true).
    true_r = np.array(c["scan_from_cad_true"], dtype=float)[:3, :3]
    nominal_r = np.array(c["scan_from_cad_nominal"], dtype=float)[:3, :3]
    off = nominal_r.T @ true_r
    angle = np.degrees(np.arccos(np.clip((np.trace(off) - 1) / 2, -1, 1)))
    return dict(path=dict(contour_info=[dict(id=k, **v) for k, v in info.items()], rows=int(len(tc))),
                pose=dict(rotation_deg=float(angle)), deformation=dict(scale=c["deformation"]["scale"]),
                geometry=dict(triangles=None))


def curve_errors(reg_csv, truth_csv, closed_ids):
    """Per contour, the largest of each registered point's distance to the true contour and each
    true point's distance to the registered contour (its points are in the path's order), mm."""
    rc, rp = read_path(reg_csv)
    tc, tp = read_path(truth_csv)
    out = {}
    for c in np.unique(tc):
        closed = int(c) in closed_ids
        r, t = rp[rc == c], tp[tc == c]
        cross = point_to_polyline(r, t, closed)
        back = point_to_polyline(t, r, closed) if len(r) > 1 else np.linalg.norm(t - r[0], axis=1)
        out[str(int(c))] = dict(curve_max=float(max(cross.max(), back.max())), cross_max=float(cross.max()))
    return out


def generate(command, p, out):
    """Writes one case into `out` with `command` (the generator's, before `--out`) and the options
    `p`; a case already written with the same options is kept."""
    done = os.path.join(out, "params.json")
    if os.path.exists(done) and json.load(open(done)) == p:
        return
    cmd = command + ["--out", out]
    for k, v in p.items():
        cmd.append("--%s=%s" % (k.replace("_", "-"), v))  # joined: a negative value is no flag
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    json.dump(p, open(done, "w"))


def read_path(fn):
    d = np.loadtxt(fn, delimiter=",", skiprows=1, ndmin=2)
    return d[:, 0].astype(np.int64), d[:, 1:4]


def point_to_polyline(q, poly, closed):
    """Distance of each point of q (n, 3) to the polyline poly (m, 3)."""
    a = poly if closed else poly[:-1]
    b = np.roll(poly, -1, axis=0) if closed else poly[1:]
    ab = b - a
    l2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30)
    out = np.empty(len(q))
    step = max(1, 2_000_000 // max(len(a), 1))
    for s in range(0, len(q), step):
        aq = q[s:s + step, None, :] - a[None]
        t = np.clip(np.einsum("ijk,jk->ij", aq, ab) / l2, 0, 1)
        out[s:s + step] = np.linalg.norm(aq - t[..., None] * ab[None], axis=2).min(axis=1)
    return out


def cross_track(reg_csv, truth_csv, closed_ids):
    rc, rp = read_path(reg_csv)
    tc, tp = read_path(truth_csv)
    return {int(c): point_to_polyline(rp[rc == c], tp[tc == c], int(c) in closed_ids)
            for c in np.unique(tc)}


def run_case(args, scorer, p):
    name = "s%d" % p["seed"]
    case = os.path.join(args.work, "cases", name)
    os.makedirs(case, exist_ok=True)
    t0 = time.time()
    generate(args.generate, p, case)
    gen_s = time.time() - t0
    res_dir = os.path.join(args.work, "results", name)
    os.makedirs(res_dir, exist_ok=True)
    reg_csv, reg_json = os.path.join(res_dir, "registered.csv"), os.path.join(res_dir, "registration.json")
    cmd = [args.trimctl, "register", "--cad", os.path.join(case, "cad.stl"),
           "--scan", os.path.join(case, "scan.ply"), "--path", os.path.join(case, "path.csv"),
           "--out", reg_csv, "--report", reg_json] + args.register_args
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall_s = time.perf_counter() - t0
    meta = own_meta(case) if args.own else json.load(open(os.path.join(case, "meta.json")))
    info = {c["id"]: c for c in meta["path"]["contour_info"]}
    row = dict(seed=p["seed"], params=p, wall_s=wall_s, gen_s=gen_s, contours=len(info),
               rotation_deg=meta["pose"]["rotation_deg"], scale=meta["deformation"]["scale"],
               rows=meta["path"]["rows"], triangles=meta["geometry"]["triangles"])
    if proc.returncode != 0 and not os.path.exists(reg_json):
        # Refused before any contour was registered (not captured, no overlap): nothing to score.
        row.update(refused=True, reason=(proc.stderr.strip().splitlines() or ["?"])[-1],
                   flagged=len(info), silent=0, false_alarms=None, bound_held=None)
        return row
    closed_ids = {i for i, c in info.items() if c.get("closed")}
    if args.own:
        per = curve_errors(reg_csv, os.path.join(case, "truth.csv"), closed_ids)
    else:
        score_json = os.path.join(res_dir, "score.json")
        subprocess.run([sys.executable, scorer, reg_csv, os.path.join(case, "truth.csv"), "--match", "curve",
                        "--json", score_json, "--quiet"], stdout=subprocess.DEVNULL)
        per = json.load(open(score_json))["per_contour"]
    rep = json.load(open(reg_json))
    cross = cross_track(reg_csv, os.path.join(case, "truth.csv"), closed_ids)
    tol = args.tolerance_um
    contours = []
    for c in rep["contours"]:
        s = per[str(c["id"])]
        true_um = 1e3 * max(s["curve_max"], s["cross_max"])
        contours.append(dict(id=c["id"], true_um=true_um, bound_um=c["predicted_max_error_um"],
                             trusted=bool(c["trustworthy"]), flags=c.get("flags", []),
                             cross_p95_um=1e3 * float(np.percentile(cross[c["id"]], 95)),
                             kind="%s/%s %s" % (info[c["id"]]["type"], info[c["id"]]["face"],
                                                info[c["id"]].get("side", ""))))
    trusted = [c for c in contours if c["trusted"]]
    pts = np.concatenate([cross[c["id"]] for c in trusted]) if trusted else np.zeros(0)
    good = [c for c in contours if c["true_um"] < tol / 2]
    row.update(
        refused=False,
        part_refused=rep["global"].get("refused"),
        part_in_doubt=rep["global"].get("in_doubt"),
        edges_in_doubt=rep["global"].get("edges_in_doubt"),
        region_in_doubt=rep["global"].get("region_in_doubt"),
        p95_um=1e3 * float(np.percentile(pts, 95)) if len(pts) else float("nan"),
        max_um=max((c["true_um"] for c in trusted), default=float("nan")),
        worst_contour_p95_um=max((c["cross_p95_um"] for c in trusted), default=float("nan")),
        all_p95_um=1e3 * float(np.percentile(np.concatenate(list(cross.values())), 95)),
        all_max_um=max(c["true_um"] for c in contours),
        flagged=sum(not c["trusted"] for c in contours),
        silent=sum(c["trusted"] and c["true_um"] > tol for c in contours),
        silent_ids=[c["id"] for c in contours if c["trusted"] and c["true_um"] > tol],
        false_alarms=sum(not c["trusted"] for c in good),
        good=len(good),
        bound_held=sum(c["true_um"] <= c["bound_um"] for c in contours),
        over_tol=sum(c["true_um"] > tol for c in contours),
        per_contour=contours,
        register_timings=rep.get("timings_s"),
    )
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--generator", required=True,
                    help="path to the outside gen_core.py, or `own` for the project's own core")
    ap.add_argument("--scorer", help="path to its score.py (default: beside the generator)")
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--set", choices=["report", "tune", "holdout", "fresh"], default="report")
    ap.add_argument("--first-seed", type=int,
                    help="with --set fresh: the range's first seed, 4001 or above, never run before")
    ap.add_argument("--only", help="comma-separated seeds (of the chosen set's numbering)")
    ap.add_argument("--points", type=int, default=200000)
    ap.add_argument("--tolerance-um", type=float, default=30.0)
    ap.add_argument("--work", default=os.path.join(REPO, "target", "outside"))
    ap.add_argument("--trimctl", default=os.path.join(REPO, "target", "release", "trimctl"))
    ap.add_argument("--json", help="write every case's figures here")
    ap.add_argument("--register-args", default="", help="extra arguments for trimctl register")
    ap.add_argument("--generate-only", action="store_true", help="write the cases, register none")
    args = ap.parse_args()
    args.register_args = args.register_args.split()
    args.own = args.generator == "own"
    scorer = None
    if args.own:
        args.generate = [args.trimctl, "synth"]
    else:
        args.generator = os.path.abspath(args.generator)
        args.generate = [sys.executable, args.generator]
        scorer = args.scorer or os.path.join(os.path.dirname(args.generator), "score.py")
    sets = ({"tune": 600, "holdout": 640, "report": 680} if args.own
            else {"report": 1001, "tune": 2001, "holdout": 3001})
    fresh_from = 800 if args.own else 4001
    if args.set == "fresh":
        if args.first_seed is None or args.first_seed < fresh_from:
            ap.error("--set fresh needs --first-seed %d or above (seeds below are the tune, "
                     "report and holdout sets)" % fresh_from)
        first = args.first_seed
    elif args.first_seed is not None:
        ap.error("--first-seed goes with --set fresh only")
    else:
        first = sets[args.set]
    params = own_params if args.own else case_params
    plan = [(first + i, i) for i in range(args.cases)]
    if args.only:
        keep = {int(s) for s in args.only.split(",")}
        plan = [(s, i) for s, i in plan if s in keep]
    head = ("%6s %5s %5s %5s %4s %4s %5s %3s %5s | %6s %6s %6s %6s | %4s %4s %5s %6s %5s %6s"
            % ("seed", "deg", "mm", "scale", "sag", "twst", "noise", "cam", "step", "P95", "max",
               "allP95", "allmax", "flag", "sil", "false", "bound", "n", "time"))
    if args.generate_only:
        for seed, index in plan:
            out = os.path.join(args.work, "cases", "s%d" % seed)
            os.makedirs(out, exist_ok=True)
            generate(args.generate, params(seed, index, args.points), out)
            print("case s%d written" % seed, flush=True)
        return
    print(head)
    print("-" * len(head))
    rows = []
    for stale in ("registered.csv", "registration.json", "score.json"):
        for seed, _ in plan:
            f = os.path.join(args.work, "results", "s%d" % seed, stale)
            if os.path.exists(f):
                os.remove(f)
    for seed, index in plan:
        p = params(seed, index, args.points)
        row = run_case(args, scorer, p)
        rows.append(row)
        pre = "%6d %5.1f %5.1f %5.3f %4.2f %4.2f %5.3f %3d %5.2f |" % (
            seed, row["rotation_deg"], p["pose_mm"], p["scale_range"], p["sag"], p["twist"], p["noise"],
            p["views"] if args.own else p["cams"], p["path_spacing"] if args.own else p["spacing"])
        if row["refused"]:
            print(pre, "refused: %s" % row["reason"][:80], flush=True)
            continue
        print(pre, "%6.1f %6.1f %6.1f %6.1f | %4d %4d %2d/%-2d %3d/%-2d %5d %5.2fs%s" % (
            row["p95_um"], row["max_um"], row["all_p95_um"], row["all_max_um"], row["flagged"],
            row["silent"], row["false_alarms"], row["good"], row["bound_held"], row["contours"],
            row["contours"], row["wall_s"],
            ("  PART REFUSED" if row["part_refused"] else "")
            + ("  PART IN DOUBT" if row.get("part_in_doubt") else "")
            + ("  EDGE IN DOUBT" if row.get("edges_in_doubt") else "")
            + ("  STRETCH IN DOUBT" if row.get("region_in_doubt") else "")
            + ("  silent %s" % row["silent_ids"][:6] if row["silent"] else "")),
            flush=True)
    ok = [r for r in rows if not r["refused"]]
    n = sum(r["contours"] for r in ok)
    tot = dict(
        cases=len(rows), refused=len(rows) - len(ok), contours=n,
        parts_refused=sum(bool(r["part_refused"]) for r in ok),
        parts_in_doubt=sum(bool(r.get("part_in_doubt")) for r in ok),
        worst_p95_um=max((r["p95_um"] for r in ok), default=float("nan")),
        worst_max_um=max((r["max_um"] for r in ok), default=float("nan")),
        worst_contour_p95_um=max((r["worst_contour_p95_um"] for r in ok), default=float("nan")),
        silent=sum(r["silent"] for r in rows),
        over_tol=sum(r["over_tol"] for r in ok),
        false_alarms=sum(r["false_alarms"] for r in ok), good=sum(r["good"] for r in ok),
        bound_held=sum(r["bound_held"] for r in ok), flagged=sum(r["flagged"] for r in ok),
        median_wall_s=float(np.median([r["wall_s"] for r in ok])) if ok else float("nan"),
    )
    print("-" * len(head))
    print("cases %d (not registered %d, parts refused %d, in doubt %d), contours %d: worst P95 %.1f um, worst max %.1f um over trusted contours "
          "(worst per-contour P95 %.1f um); silent misses %d (contours over tolerance %d); false alarms %d of "
          "%d (%.1f %%); bound held %d of %d (%.1f %%); flagged %d; median register wall %.2f s" % (
              tot["cases"], tot["refused"], tot["parts_refused"], tot["parts_in_doubt"], n, tot["worst_p95_um"], tot["worst_max_um"],
              tot["worst_contour_p95_um"], tot["silent"], tot["over_tol"], tot["false_alarms"], tot["good"],
              100 * tot["false_alarms"] / max(tot["good"], 1), tot["bound_held"], n,
              100 * tot["bound_held"] / max(n, 1), tot["flagged"], tot["median_wall_s"]))
    if args.json:
        json.dump(dict(totals=tot, cases=rows), open(args.json, "w"), indent=1)


if __name__ == "__main__":
    main()
