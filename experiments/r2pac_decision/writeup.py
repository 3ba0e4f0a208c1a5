"""Where R2PAC's reward went, task by task, before and after each candidate (PROTOCOL.md's
write-up): the tables the write-up in RESULTS.md is read off. Run after the decision: it prints
scores.

    python experiments/r2pac_decision/writeup.py [--cells experiments/r2pac_decision/cells]
        [--selection RUNS]   # also re-evaluate each baseline cell's run found under RUNS
        [--out experiments/r2pac_decision/where_reward_went.md]

From each kept cell (the decision's seeds 0-2 and, once kept, the confirmation's seeds 3-5):
the scores, the evaluation's diagnostics (results.json: episode length,
the share ended by a true terminal, how often the choice is not the first candidate, the Qbar_r
it gives up, the candidates' spreads, the share of visited states with V_c > l) and, where the
cell's metrics.jsonl was kept, the training's (the end of the critic phase: V_c's batch minimum,
Qbar_r's RMSE to its penalised and to the unpenalised targets; the end of the actor phase:
corr(Abar_r, R_t) and the CFG labels' balance in safe and unsafe states). `--selection` adds, for
each baseline cell whose run is on this machine, `python -m r2pac_jax.evaluate`'s three
selection rules side by side, kept as `selection.json` beside the cell.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
CANDIDATES = ("0", "a", "b", "c")
NAMES = {"0": "0 (default)", "a": "a (LayerNorm critics)", "b": "b (V_c >= 0)", "c": "c (both)"}
EVAL = (("terminal_share", "ended by a terminal", None), ("mean_length", "length", None),
        ("not_first", "not the first", "diagnostics"),
        ("qr_given_up", "Qbar_r given up", "diagnostics"),
        ("qc_spread", "Q_c spread", "diagnostics"), ("qr_spread", "Qbar_r spread", "diagnostics"),
        ("unsafe_state", "V_c > l", "diagnostics"))
TRAIN = (("vc_min", "V_c min", "critic", min), ("qr_rmse_penalised", "Qbar_r RMSE, penalised",
                                                  "critic", None),
         ("qr_rmse_unpenalised", "Qbar_r RMSE, unpenalised", "critic", None),
         ("corr_adv_r_reward_safe", "corr(Abar_r, R), safe", "actor", None),
         ("label_balance_safe", "labels, safe", "actor", None),
         ("label_balance_unsafe", "labels, unsafe", "actor", None))


def cell_dirs(root: Path, seeds: str = "seeds0-2") -> dict[str, dict[str, Path]]:
    """task -> candidate -> kept cell folder (those with a results.json)."""
    out: dict = {}
    for f in sorted((root / seeds).glob("*/*/results.json")):
        out.setdefault(f.parent.parent.name, {})[f.parent.name] = f.parent
    return out


def _mean(x):
    return None if x is None else x.get("mean")


def eval_row(res: dict) -> dict:
    """The evaluation's numbers of a cell (seed means)."""
    row = dict(reward=_mean(res["normalized_reward"]), cost=_mean(res["normalized_cost"]))
    for key, _, where in EVAL:
        src = res.get(where, {}) if where else res
        row[key] = _mean(src.get(key))
    return row


def train_row(metrics: list[dict]) -> dict:
    """The last block of each phase, averaged over the lanes (V_c's minimum: the lanes' minimum)."""
    out = {}
    for key, _, phase, agg in TRAIN:
        rows = [r for r in metrics if r.get("phase") == phase and r.get(key) is not None]
        if not rows:
            out[key] = None
            continue
        last = max(r["step"] for r in rows)
        vals = [float(r[key]) for r in rows if r["step"] == last]
        out[key] = (agg or statistics.fmean)(vals)
    return out


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3g}"


def _cell_tables(cells: dict, candidates) -> tuple[list, list, list]:
    """The evaluation rows, training rows and cells without kept metrics of `cells`
    (task -> candidate -> folder), in the candidates' order."""
    ev_lines, train_lines, missing_train = [], [], []
    for task, by in cells.items():
        for c in candidates:
            d = by.get(c)
            if d is None:
                ev_lines.append(f"| {task} | {NAMES[c]} | not run | | " + "| " * len(EVAL))
                continue
            ev = eval_row(json.loads((d / "results.json").read_text()))
            ev_lines.append(f"| {task} | {NAMES[c]} | {_fmt(ev['reward'])} | "
                            f"{_fmt(ev['cost'])} | " + " | ".join(_fmt(ev[e[0]]) for e in EVAL)
                            + " |")
            m = d / "metrics.jsonl"
            if m.is_file():
                rows = [json.loads(ln) for ln in m.read_text().splitlines() if ln.strip()]
                tr = train_row(rows)
                train_lines.append(f"| {task} | {NAMES[c]} | "
                                   + " | ".join(_fmt(tr[t[0]]) for t in TRAIN) + " |")
            else:
                missing_train.append(f"{task}/{c}")
    return ev_lines, train_lines, missing_train


EVAL_HEAD = ["| task | candidate | reward | cost | " + " | ".join(e[1] for e in EVAL) + " |",
             "|---|---|---|---|" + "---|" * len(EVAL)]
TRAIN_HEAD = ["| task | candidate | " + " | ".join(t[1] for t in TRAIN) + " |",
              "|---|---|" + "---|" * len(TRAIN)]


def tables(root: Path) -> str:
    cells = cell_dirs(root)
    ev, train, missing_train = _cell_tables(cells, CANDIDATES)
    lines = ["# Where R2PAC's reward went: the decision tasks before and after", "",
             "From `experiments/r2pac_decision/writeup.py` over the kept cells (seeds 0-2, CPU "
             "quick preset, 20 evaluation episodes per seed; seed means).", "",
             "## Evaluation", ""] + EVAL_HEAD + ev
    train_lines = ["", "## Training (the last block of each phase; cells whose metrics were kept)",
                   ""] + TRAIN_HEAD + train
    sel_lines = ["", "## Selection rules on the baseline cells (`python -m r2pac_jax.evaluate`, "
                 "evaluation keys of seed 123)", ""]
    for task, by in cells.items():
        s = by.get("0", Path("/nonexistent")) / "selection.json"
        if s.is_file():
            from r2pac_jax.evaluate import selection_table

            sel = json.loads(s.read_text())
            sel_lines += [f"{task}:", "", selection_table(sel["results"], sel["trained"]), ""]
    if missing_train:
        train_lines += ["", "No training metrics kept (run on a machine that is gone, before "
                        "`run.sh keep` kept them): " + ", ".join(missing_train) + "."]
    conf = cell_dirs(root, "seeds3-5")
    conf_lines = []
    if conf:  # the confirmation: the baseline and the winner, the same diagnostics
        ids = [c for c in CANDIDATES if any(c in by for by in conf.values())]
        ev, train, missing = _cell_tables(conf, ids)
        conf_lines = ["", "## Confirmation (seeds 3-5): the same diagnostics, baseline and winner",
                      "", "Evaluation:", ""] + EVAL_HEAD + ev + [
                      "", "Training (the last block of each phase):", ""] + TRAIN_HEAD + train
        if missing:
            conf_lines += ["", "No training metrics kept: " + ", ".join(missing) + "."]
    return "\n".join(lines + train_lines + sel_lines + conf_lines)


def add_selection(root: Path, runs: Path, episodes: int = 20, log=print) -> list[str]:
    """selection.json beside each kept baseline cell whose run is under `runs` (same layout)."""
    from r2pac_jax.evaluate import evaluate_run, selection_rules
    from r2pac_jax.io import atomic_write_json

    done = []
    for task, by in cell_dirs(root).items():
        d = by.get("0")
        run = runs / "seeds0-2" / task / "0"
        if d is None or (d / "selection.json").is_file() or not (run / "policy").is_dir():
            continue
        rules = selection_rules(run)
        res = {r: evaluate_run(run, episodes, r) for r in rules}
        # atomic_write_json writes the arrays as lists
        atomic_write_json(d / "selection.json", dict(trained=rules[0], episodes=episodes,
                                                      seed=123, results=res))
        log(f"{task}: selection rules kept in {d / 'selection.json'}")
        done.append(task)
    return done


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="writeup.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", default=str(HERE / "cells"))
    ap.add_argument("--selection", metavar="RUNS", help="the runs folder of the cells "
                    "(runs/r2pac_decision): re-evaluate the baseline cells found there")
    ap.add_argument("--out", default=str(HERE / "where_reward_went.md"))
    args = ap.parse_args(argv)
    root = Path(args.cells)
    if not (root / "seeds0-2").is_dir():
        print(f"error: {root}/seeds0-2 holds no kept cell", file=sys.stderr)
        return 2
    if args.selection:
        add_selection(root, Path(args.selection))
    md = tables(root)
    from r2pac_jax.io import atomic_write_text

    atomic_write_text(Path(args.out), md + "\n")
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
