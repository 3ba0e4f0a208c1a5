"""Each learned-behaviour file beside DSRL's published statistics, one row per task with a
recipe, written into GENERATION.md between its `dsrl-compare` markers (and printed):

  python experiments/data_factory/dsrl_compare.py [--write]

DSRL's side is what it published: the trajectory count and cost cap of each file (its file
names, e.g. SafetyCarGoal1Gymnasium-v0-120-1671), the normalisation constants R_min / R_max
(`dsrl/infos.py`) and the RL budget (`scripts/train_trpol_v0.py`: epochs x 10k steps): the
registry holds them (`r2pac_jax/tasks/`). Our side is read from each file's card as committed in
`results_v2/TASK/` (the file the Table-1 manifest pins when there is one), so the table needs no
HDF5 file on this machine.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Optional

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
ARCHIVE = HERE / "results_v2"
MANIFEST = ROOT / "experiments/table1/cpu-quick/manifest.json"
DOC = HERE / "GENERATION.md"
START, END = "<!-- dsrl-compare:start -->", "<!-- dsrl-compare:end -->"


def find_card(task: str, archive: Path = ARCHIVE, pinned: Optional[str] = None) -> Optional[Path]:
    """The card of the task's current file: the pinned one, else the only (or last by name)
    learned-v2 card directly in results_v2/TASK (superseded files sit in subfolders)."""
    d = archive / task
    if pinned:
        p = d / (pinned[:-len(".hdf5")] + ".json")
        if p.is_file():
            return p
    cards = sorted(d.glob(f"{task}-generated-ppolag-v2-*.json")) if d.is_dir() else []
    return cards[-1] if cards else None


def row(task, card: Optional[dict]) -> dict:
    """One comparison row: DSRL's published numbers and the card's (None where no file)."""
    c = task.collection
    out = dict(task=task.name, dsrl_trajectories=c.trajectories, dsrl_cost_cap=c.cost_cap,
               r_min=task.r_min, r_max=task.r_max, kappa=task.kappa,
               dsrl_env_steps=c.env_steps)
    if card is None:
        return out
    n = card["trajectories"]
    out.update(file_trajectories=n, env_steps=card["generation"]["env_steps"],
               best=card["normalised_return_range"][1], worst=card["normalised_return_range"][0],
               cost_min=card["cost_range"][0], cost_max=card["cost_range"][1],
               safe_share=card["safe_trajectories"] / n if n else None)
    return out


def _m(x: float) -> str:
    return f"{x / 1e6:.3g}M"


def markdown(rows: list) -> str:
    head = ("| task | DSRL trajectories | ours | DSRL cost cap | our cost range | R_min .. R_max "
            "(DSRL) | our normalised return, worst .. best | safe share (cost <= kappa) | RL "
            "budget, ours / DSRL's |\n|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        if "file_trajectories" not in r:
            lines.append(f"| {r['task']} | {r['dsrl_trajectories']:,} | no file | "
                         f"{r['dsrl_cost_cap']:g} | - | {r['r_min']:.4g} .. {r['r_max']:.4g} | - "
                         f"| - | - / {_m(r['dsrl_env_steps'])} |")
            continue
        share = r["env_steps"] / r["dsrl_env_steps"]
        lines.append(
            f"| {r['task']} | {r['dsrl_trajectories']:,} | {r['file_trajectories']:,} | "
            f"{r['dsrl_cost_cap']:g} | {r['cost_min']:g} .. {r['cost_max']:g} | "
            f"{r['r_min']:.4g} .. {r['r_max']:.4g} | {r['worst']:.2f} .. {r['best']:.2f} | "
            f"{100 * r['safe_share']:.1f}% (kappa {r['kappa']:g}) | {_m(r['env_steps'])} / "
            f"{_m(r['dsrl_env_steps'])}{'' if share >= 1 else f' ({100 * share:.0f}%)'} |")
    return "\n".join(lines)


def replace_section(text: str, body: str) -> str:
    """The text with the part between the markers replaced (the markers appended at the end,
    under a heading, where absent)."""
    block = f"{START}\n{body}\n{END}"
    if START in text and END in text:
        return re.sub(re.escape(START) + r".*?" + re.escape(END), lambda _: block, text,
                      flags=re.S)
    return (text.rstrip("\n") + "\n\n## Each file beside DSRL's published statistics\n\n"
            "`python experiments/data_factory/dsrl_compare.py --write` (from the committed "
            "cards; DSRL's numbers from its file names, `dsrl/infos.py` and "
            "`scripts/train_trpol_v0.py`).\n\n" + block + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--write", action="store_true", help=f"write the table into {DOC.name}")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from r2pac_jax.tasks import get_task, list_tasks

    pinned = json.loads(MANIFEST.read_text())["datasets"] if MANIFEST.exists() else {}
    rows = []
    for name in list_tasks():
        t = get_task(name)
        if t.collection is None or t.family == "demo":
            continue
        p = find_card(name, pinned=pinned.get(name, {}).get("file"))
        rows.append(row(t, json.loads(p.read_text()) if p else None))
    md = markdown(rows)
    missing = [r["task"] for r in rows if "file_trajectories" not in r]
    md += (f"\n\n{len(rows) - len(missing)} of {len(rows)} tasks have a file"
           + (f"; none yet for {', '.join(missing)}." if missing else "."))
    print(md)
    if a.write:
        from r2pac_jax.io import atomic_write_text

        atomic_write_text(DOC, replace_section(DOC.read_text(), md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
