#!/usr/bin/env python3
"""Relative RMS error of estimates at points against a reference, as livebake's
RelativeRmsError computes it: sqrt(max(sum |got - want|^2 - sum sigma^2, 0) / sum |want|^2),
the reference's own variance removed in quadrature.

    scripts/relative_rms.py ESTIMATE.json REFERENCE.json [--only floor,wall,ceiling]

Both files are in probe's output format ({"points":[{"p":..,"n":..,"E":[r,g,b],
"E_stderr":[r,g,b]}, ...]}; E_stderr is read from the reference, optional), points in the same
order. Also prints the mean ratio of the estimate's luminance to the reference's (its bias).
"""
import json
import sys


def main():
    est = json.load(open(sys.argv[1]))["points"]
    ref = json.load(open(sys.argv[2]))["points"]
    if len(est) != len(ref):
        sys.exit(f"{len(est)} estimates against {len(ref)} reference points")
    err = want2 = var = 0.0
    ratios = []
    for e, r in zip(est, ref):
        if max(abs(a - b) for a, b in zip(e["p"], r["p"])) > 1e-5:
            sys.exit(f"points differ: {e['p']} vs {r['p']}")
        s = r.get("E_stderr", [0.0, 0.0, 0.0])
        err += sum((a - b) ** 2 for a, b in zip(e["E"], r["E"]))
        want2 += sum(b * b for b in r["E"])
        var += sum(x * x for x in s)
        lum = lambda c: 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
        if lum(r["E"]) > 0:
            ratios.append(lum(e["E"]) / lum(r["E"]))
    value = (max(err - var, 0.0) / want2) ** 0.5 if want2 > 0 else 0.0
    bias = sum(ratios) / len(ratios) - 1.0 if ratios else 0.0
    print(json.dumps({"points": len(est), "relative_rms": value, "mean_bias": bias}))


if __name__ == "__main__":
    main()
