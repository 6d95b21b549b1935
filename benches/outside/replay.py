#!/usr/bin/env python3
"""replay.py -- a bound rule tried on saved outside runs, without registering again.

Each case's registration.json holds every term of a contour's bound (the posterior's deviation
`field_sigma_mm`, the model check's `model_disagreement_mm`, the coverage and, backed out of
`predicted_max_error_um`, the residual excess), and outside.py's --json holds its true error.
This recomputes each contour's bound under a rule, flags it as the registration would (its
other flags kept; in a part in doubt, a bound at 1.5 sigma over half the tolerance), and prints
silent misses, false alarms and bound coverage per set. The part's in-doubt verdict is taken as
it was, so a rule that changes which parts are in doubt is only approximated: run the real
registration before taking one.

    replay.py --set WORK JSON [--set WORK JSON ...] [--rule linear|quadrature] [--scale K]

WORK is an outside.py --work folder (its results/s<seed>/registration.json), JSON its --json.
`--rule linear --scale 1` reproduces the registration's flags (the constants of
trim_register::regional::quality, copied below); it prints how many contours differ.
"""
import argparse
import json
import math
import os

# trim_register::regional::quality (BOUND_*, PART_BOUND_SIGMA_FACTOR).
SIGMA_FACTOR, PART_SIGMA_FACTOR = 2.1, 1.5
BIAS_UM, MODEL_FACTOR, COVERAGE_FACTOR = 4.0, 1.5, 0.5
TOLERANCE_UM, DOUBT_FRACTION = 30.0, 0.5


def coverage_factor(c):
    return 1.0 + COVERAGE_FACTOR * (1.0 - min(max(c["coverage"], 0.0), 1.0))


def terms(c):
    """(sigma, model, residual excess, coverage factor), µm, of a registration.json contour."""
    sigma = 1e3 * c["field_sigma_mm"]
    model = 1e3 * c["model_disagreement_mm"]
    cf = coverage_factor(c)
    excess = c["predicted_max_error_um"] / cf - SIGMA_FACTOR * sigma - BIAS_UM - MODEL_FACTOR * model
    return sigma, model, max(excess, 0.0), cf


def bound(rule, scale, t, factor):
    sigma, model, excess, cf = t
    if rule == "linear":
        return scale * (factor * sigma + BIAS_UM + excess + MODEL_FACTOR * model) * cf
    return (scale * math.hypot(factor * sigma, MODEL_FACTOR * model) + BIAS_UM + excess) * cf


def load(work, js):
    cases = []
    for row in json.load(open(js))["cases"]:
        rep = os.path.join(work, "results", "s%d" % row["seed"], "registration.json")
        if "per_contour" not in row or not os.path.exists(rep):
            continue
        report = json.load(open(rep))
        by_id = {c["id"]: c for c in report["contours"]}
        contours = [(pc, by_id[pc["id"]]) for pc in row["per_contour"]]
        cases.append((report["global"]["in_doubt"] is not None, contours))
    return cases


def replay(cases, rule, scale):
    silent = alarms = good = held = n = differ = 0
    for in_doubt, contours in cases:
        for truth, c in contours:
            t = terms(c)
            b = bound(rule, scale, t, SIGMA_FACTOR)
            doubt = bound(rule, scale, t, PART_SIGMA_FACTOR)
            other = [f for f in c["flags"] if f not in ("predicted_error", "part_in_doubt")]
            flagged = bool(other) or b > TOLERANCE_UM or (
                in_doubt and doubt > DOUBT_FRACTION * TOLERANCE_UM)
            differ += flagged == c["trustworthy"]
            n += 1
            held += truth["true_um"] <= b
            if truth["true_um"] < TOLERANCE_UM / 2:
                good += 1
                alarms += flagged
            if truth["true_um"] > TOLERANCE_UM and not flagged:
                silent += 1
    return dict(silent=silent, false_alarms=100.0 * alarms / max(good, 1),
                bound_held=100.0 * held / max(n, 1), contours=n, flags_differing=differ)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", nargs=2, action="append", metavar=("WORK", "JSON"), required=True)
    ap.add_argument("--rule", choices=["linear", "quadrature"], default="linear")
    ap.add_argument("--scale", type=float, default=1.0)
    args = ap.parse_args()
    for work, js in args.set:
        r = replay(load(work, js), args.rule, args.scale)
        print("%-40s silent %d, false alarms %.2f %%, bound held %.1f %% of %d contours "
              "(%d flags differ from the report's)" % (
                  work, r["silent"], r["false_alarms"], r["bound_held"], r["contours"],
                  r["flags_differing"]))


if __name__ == "__main__":
    main()
