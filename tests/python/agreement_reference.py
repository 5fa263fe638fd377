"""Reference values for `assay agreement`, computed with scipy (independently of Assay's Rust code).

Run (with scipy installed: pip install scipy numpy): python tests/python/agreement_reference.py examples/agreement/paper-table4-scene-alignment.csv
Prints, per dataset and model: n, Pearson r, MAE, r/MAE, Spearman rho, Kendall tau-b (None where
undefined). The numbers are pinned in crates/domain/stats/src/agreement.rs's tests.
"""
import csv
import sys

import numpy as np
from scipy import stats


def number(cell):
    return float(cell.split("(")[0])


def main(path):
    with open(path) as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    header, rows = rows[0], rows[1:]
    h = header.index("human")
    judges = [i for i, c in enumerate(header) if i > h]
    for dataset in sorted({r[0] for r in rows}):
        sub = [r for r in rows if r[0] == dataset]
        human = np.array([number(r[h]) for r in sub])
        for j in judges:
            model = np.array([number(r[j]) for r in sub])
            mae = float(np.mean(np.abs(model - human)))
            if np.ptp(model) == 0 or np.ptp(human) == 0:
                r = rho = tau = None
            else:
                r = float(stats.pearsonr(human, model)[0])
                rho = float(stats.spearmanr(human, model)[0])
                tau = float(stats.kendalltau(human, model)[0])
            ratio = None if r is None else r / mae
            print(f'("{dataset}", "{header[j]}", {len(sub)}, {r!r}, {mae!r}, {ratio!r}, {rho!r}, {tau!r}),')


if __name__ == "__main__":
    main(sys.argv[1])
