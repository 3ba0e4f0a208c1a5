"""Markdown tables from compare.py's and diagnose.py's JSON lines (for benchmarks/FIDELITY.md).

    python benchmarks/fidelity/report.py compare.jsonl [more.jsonl ...] [--diagnose diag.jsonl]
"""
from __future__ import annotations

import argparse
import json


def fmt(x) -> str:
    return "0" if x == 0 else f"{x:.1e}"


def steps(v) -> str:
    return ", ".join("-" if s is None else str(s) for s in v)


def compare_table(rows: list) -> str:
    out = ["| task | physics | mode | steps | obs | reward | qpos | qvel | cost flips | "
           "terminal flips | obs err > 1e-3 from step | original's first terminal |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append("| " + " | ".join([
            r["task"], r["physics"], r["mode"].replace("_", " "), str(r["horizon"]),
            fmt(r["max_err_obs"]), fmt(r["max_err_reward"]), fmt(r["max_err_qpos"]),
            fmt(r["max_err_qvel"]), str(r["cost_disagree"]), str(r["terminated_disagree"]),
            steps(r["first_obs_err_over_1e-3"]), steps(r["ref_first_terminal"])]) + " |")
    return "\n".join(out)


def episodes_table(rows: list) -> str:
    out = ["| task | episodes | return: original / ours (+- s.e.) | cost | length | "
           "normalised reward diff | normalised cost diff |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [f"{r[k]['ref_mean']:.2f} +- {r[k]['ref_se']:.2f} / "
                 f"{r[k]['ours_mean']:.2f} +- {r[k]['ours_se']:.2f} "
                 f"({r[k]['diff_over_se']:+.1f} s.e.)" for k in ("returns", "costs", "lengths")]
        out.append(f"| {r['task']} | {r['episodes']} | " + " | ".join(cells) +
                   f" | {r['normalized_reward_diff']:+.4f} | {r['normalized_cost_diff']:+.4f} |")
    return "\n".join(out)


def diagnose_tables(rows: list) -> str:
    exps = sorted({r["experiment"] for r in rows if r["kind"] == "raw_one_step"},
                  key=["as_is", "unhalved_margins", "euler_both"].index)
    out = ["| task | " + " | ".join(f"{e}: qpos / qvel" for e in exps) +
           " | original vs itself (qvel0 + 1e-12) | ours vs original |",
           "|---|" + "---|" * (len(exps) + 2)]
    for task in dict.fromkeys(r["task"] for r in rows):
        cells = []
        for e in exps:
            rr = [r for r in rows if r["task"] == task and r.get("experiment") == e]
            cells.append(f"{fmt(max(r['max_err_qpos'] for r in rr))} / "
                         f"{fmt(max(r['max_err_qvel'] for r in rr))}")
        ch = [r for r in rows if r["task"] == task and r["kind"] == "chaos"]
        cells.append(steps([r["ref_vs_ref_perturbed_1e12"] for r in ch]))
        cells.append(steps([r["ours_vs_ref"] for r in ch]))
        out.append(f"| {task} | " + " | ".join(cells) + " |")
    diffs = [f"- {r['task']}: " + ("; ".join(r["diffs"]) or "none")
             for r in rows if r["kind"] == "model_diff"]
    return "\n".join(out) + "\n\nCompiled-model differences (every numeric mjModel array, " \
        "visual fields skipped):\n" + "\n".join(diffs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="*")
    ap.add_argument("--diagnose", default=None)
    args = ap.parse_args()
    rows = [json.loads(line) for f in args.files for line in open(f) if line.strip()]
    steps_rows = [r for r in rows if r["mode"] != "episodes"]
    if steps_rows:
        print(compare_table(steps_rows))
    if len(steps_rows) < len(rows):
        print()
        print(episodes_table([r for r in rows if r["mode"] == "episodes"]))
    if args.diagnose:
        print()
        print(diagnose_tables([json.loads(line) for line in open(args.diagnose) if line.strip()]))


if __name__ == "__main__":
    main()
