"""The staged question's error rates and costs by simulation: the tables of docs/question.md.

    python benchmarks/question_calibration.py [--trials 20000]

1. For each law and ratio σ_between/σ_within, with the shipped design (nested seeds, futility,
   the payoff seed rule): the share of rows with no effect decided (over all looks), the share
   of rows whose effect equals the margin called equivalent, the family-wise error of 15 rows
   correlated 0.8 (none with an effect), the power and mean draws per model at 2 σ_between.
2. At the measured components, each design (today's crossed seeds; nested; nested with
   futility; nested with futility and the payoff rule): rows settled, CPU-hours, wrong verdicts.

The same functions the test suite holds to its bounds (cape.study.stats.sequential_calibration).
"""

from __future__ import annotations

import argparse

from cape.study.stats import sequential_calibration as calib
from cape.study.stats.sequential import Design


def laws(design: Design, trials: int) -> None:
    print(
        "| law | σ_b/σ_w | decided with no effect | `equivalent` at the margin | family error "
        "(15 null rows, ρ 0.8) | power at 2 σ_b | mean draws used |"
    )
    print("|---|---|---|---|---|---|---|")
    for law in calib.LAWS:
        for ratio in (0.2, 1.0, 10.0) if law in calib.CONTINUOUS else (1.0,):
            margin = max(ratio, 1.0)
            effect = 2 * ratio if law in calib.CONTINUOUS else 2.0
            false = calib.false_verdict_rate(design, law, ratio, margin=margin, trials=trials)
            eq = calib.false_equivalence_rate(design, law, margin, ratio, trials=trials)
            family = "–"
            if law in calib.CONTINUOUS:
                n = trials // 10
                error = calib.family_error(design, law, 15, 0, 0.0, margin, ratio, n, 0.8)
                family = f"{error:.1%}"
            power, used = calib.power(design, law, effect, ratio, margin, trials=trials)
            print(
                f"| {law} | {ratio:g} | {false:.2%} | {eq:.2%} | {family} | {power:.1%} | "
                f"{used:.1f} |"
            )


def designs(trials: int) -> None:
    print("| components | design | rows settled | CPU-hours | rows wrong | questions wrong |")
    print("|---|---|---|---|---|---|")
    cases = (
        ("issue 58's five rows, measured effects", calib.ISSUE_COMPONENTS, False),
        ("issue 58's five rows, no effect", calib.ISSUE_COMPONENTS, True),
        ("docs' seven rows, no effect", calib.DOCS_COMPONENTS, True),
    )
    for label, components, null in cases:
        for r in calib.compare_designs(components, trials=trials, null=null):
            print(
                f"| {label} | {r['design']} | {r['settled']:.2f} of {len(components)} | "
                f"{r['cpu_h']:.1f} | {r['wrong_rows']:.2%} | {r['wrong_questions']:.1%} |"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20000, help="rows per case (%(default)s)")
    parser.add_argument("--stages", type=int, nargs="+", default=[3, 6, 10, 15, 20])
    parser.add_argument("--rows", type=int, default=15)
    parser.add_argument("--futility", type=float, default=0.05)
    args = parser.parse_args()
    laws(Design(tuple(args.stages), args.rows, futility=args.futility), args.trials)
    print()
    designs(max(args.trials // 5, 500))


if __name__ == "__main__":
    main()
