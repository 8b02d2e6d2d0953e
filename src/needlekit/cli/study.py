"""``needlekit study``: studies over many real cases, one table each."""

from __future__ import annotations

import argparse

from needlekit.cli._common import EXIT_OK, _fmt_table


def _cmd_study_livers(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from needlekit.planning.straight.coverage import fraction_text
    from needlekit.studies.liver_study import liver_cases, run_liver_study

    cases = liver_cases(args.medrad, args.livers)  # bad folders and patients fail here, at once
    with tqdm(total=len(cases) * len(args.gamma), desc="livers", unit="case", disable=None) as bar:

        def progress(row: dict) -> None:
            bar.update(1)
            bar.set_postfix_str(f"liver {row['patient']} {row['nodule']}: {row['status']}")

        record = run_liver_study(
            args.out,
            medrad_dir=args.medrad,
            livers=args.livers,
            gammas_mm=args.gamma,
            resolution_deg=args.resolution_deg,
            cache_dir=args.cache_dir,
            use_cache=not args.no_cache,
            progress=progress,
        )
    rows = []
    for r in record["rows"]:
        clear = "-" if r["min_clearance_mm"] is None else f"{r['min_clearance_mm']:.2f}"
        check = {True: "ok", False: "VIOLATED", None: "-"}[r["verified"]]
        rows.append(
            [
                r["patient"], r["nodule"], r["start"], f"{r['gamma_mm']:g}", r["status"],
                f"{r['needles_planned']} of {r['needles_chosen']}",
                f"{fraction_text(r['coverage'])} ({fraction_text(r['tumour_coverage'])})", clear,
                f"{r['healthy_ablated_ml']:.1f}", f"{r['plan_s']:.1f}", check,
            ]
        )  # fmt: skip
    print(
        _fmt_table(
            ["liver", "nodule", "start", "gamma", "status", "needles", "coverage (tumour)",
             "min clear", "healthy mL", "plan s", "check"],
            rows,
        )
    )  # fmt: skip
    for r in record["rows"]:
        if r["reason"]:
            print(f"liver {r['patient']} {r['nodule']} gamma {r['gamma_mm']:g}: {r['reason']}")
    s = record["summary"]
    print(
        f"{s['cases']} cases: {s['covered']} covered, {s['not_covered']} not covered, "
        f"{s['blocked']} blocked; {s['verified']} plans checked ok, {s['violations']} "
        f"violations ({record['wall_s']:.0f} s) -> {args.out}"
    )
    return EXIT_OK if s["violations"] == 0 else 1
