"""Reference values for `assay rank`, computed with scipy (independently of Assay's Rust code).

Run (with scipy installed: pip install scipy numpy): python tests/python/ranking_reference.py examples/rank/ladder.csv
Reads a success table (task, policy, source, and trials + successes or success_rate/rate/success),
and for every proxy source against `real` prints, per policy, R (real) and R_S (proxy), each the
mean over the tasks both sources have of the success rate (exact fractions when counts are known),
then Pearson r, Spearman rho, Kendall tau-b (scipy) and MMRV(proxy, real) as ../shared/DESIGN.md
pins it. The numbers are pinned in crates/domain/stats/src/ranking.rs's tests.
"""
import csv
import sys
from fractions import Fraction

import scipy
from scipy import stats


def rate(row):
    if row.get("trials") not in (None, "") and row.get("successes") not in (None, ""):
        return Fraction(int(row["successes"]), int(row["trials"]))
    for name in ("success_rate", "rate", "success"):
        if row.get(name) not in (None, ""):
            return float(row[name])
    raise ValueError(row)


def mean(values):
    if all(isinstance(v, Fraction) for v in values):
        return float(sum(values, Fraction(0)) / len(values))
    return sum(float(v) for v in values) / len(values)


def mmrv(sim, real):
    n = len(real)
    worst = [
        max([abs(real[i] - real[j]) for j in range(n) if (sim[i] > sim[j]) != (real[i] > real[j])] or [0.0])
        for i in range(n)
    ]
    return sum(worst) / n


def main(path, real_source="real"):
    with open(path) as f:
        rows = list(csv.DictReader(line for line in f if line.strip() and not line.lstrip().startswith("#")))
    cells = {(r["source"], r["task"], r["policy"]): rate(r) for r in rows}
    sources = list(dict.fromkeys(r["source"] for r in rows))
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    print(f"# scipy {scipy.__version__}")
    for proxy in [s for s in sources if s != real_source]:
        names, real, sim = [], [], []
        for p in policies:
            common = [t for t in tasks if (real_source, t, p) in cells and (proxy, t, p) in cells]
            if not common:
                continue
            names.append(p)
            real.append(mean([cells[(real_source, t, p)] for t in common]))
            sim.append(mean([cells[(proxy, t, p)] for t in common]))
        print(f"# {proxy} against {real_source}")
        for p, r, s in zip(names, real, sim):
            print(f'("{p}", {r!r}, {s!r}),')
        print(f"pearson = {float(stats.pearsonr(sim, real)[0])!r}")
        print(f"spearman = {float(stats.spearmanr(sim, real)[0])!r}")
        print(f"kendall_tau_b = {float(stats.kendalltau(sim, real)[0])!r}")
        print(f"mmrv = {mmrv(sim, real)!r}")


if __name__ == "__main__":
    main(*sys.argv[1:])
