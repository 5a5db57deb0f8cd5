"""The staged question's error rates by simulation, the table of docs/question.md.

    python benchmarks/question_calibration.py [--trials 20000]

For each law (normal, skewed, integer failure counts) and ratio σ_between/σ_within: the share of
rows with no effect decided (over all looks), the share of rows whose effect equals the margin
called equivalent, the family-wise error of 15-row families (8 null, 7 with 2 σ_between), and
the power and mean draws per model used at an effect of 2 σ_between (cape.study.
sequential_calibration, the same functions the test suite holds to 5 %).
"""

from __future__ import annotations

import argparse

from cape.study import sequential_calibration as calib
from cape.study.sequential import Design


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20000, help="rows per case (%(default)s)")
    parser.add_argument("--stages", type=int, nargs="+", default=[3, 6, 10, 15, 20])
    parser.add_argument("--rows", type=int, default=15)
    args = parser.parse_args()
    design = Design(tuple(args.stages), args.rows)
    print(
        "| law | σ_b/σ_w | false verdict, no effect | equivalent at the margin | family error "
        "| power at 2 σ_b | mean draws used |"
    )
    print("|---|---|---|---|---|---|---|")
    for law in calib.LAWS:
        for ratio in (0.2, 1.0, 10.0) if law != "failures" else (1.0,):
            margin = max(ratio, 1.0) if law != "failures" else 1.0
            effect = 2 * ratio if law != "failures" else 2.0
            n = args.trials
            false = calib.false_verdict_rate(design, law, ratio, margin=margin, trials=n)
            eq = calib.false_equivalence_rate(design, law, margin, ratio, trials=n)
            fam = calib.family_error(design, law, 8, 7, max(effect, margin), margin, ratio,
                                     trials=n // 10)  # fmt: skip
            power, used = calib.power(design, law, effect, ratio, trials=n)
            print(
                f"| {law} | {ratio:g} | {false:.2%} | {eq:.2%} | {fam:.1%} | {power:.1%} | "
                f"{used:.1f} |"
            )


if __name__ == "__main__":
    main()
