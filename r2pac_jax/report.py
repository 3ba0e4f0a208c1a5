"""Tables in the paper's Table 1 format and PNG plots (dataset composition, training curves)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from r2pac_jax.io import atomic_path

SAFE_LIMIT = 1.0  # a policy is safe when its normalised cost is below 1


def _fmt(x: float) -> str:
    return f"{x:.2f}"


def _cell_marks(row: dict) -> dict[str, str]:
    """{algo: "★" | "☆"} for the best and second-best reward among the row's safe agents."""
    safe = {a: r["normalized_reward"]["mean"] for a, r in row.items()
            if _is_safe(r) and r["normalized_reward"]["mean"] is not None}
    ranked = sorted(safe, key=safe.get, reverse=True)
    return dict(zip(ranked, ("★", "☆")))


def _is_safe(r: dict) -> bool:
    c = r["normalized_cost"]["mean"]
    return c is not None and c < SAFE_LIMIT


def _family_rows(cells: dict, columns: Sequence[str], families: dict) -> dict[str, dict]:
    """Per-family averages over the family's tasks of each algorithm's means (an algorithm
    missing or diverged on one of the family's tasks gets no average)."""
    out: dict[str, dict] = {}
    for fam in dict.fromkeys(families[t] for t in cells if t in families):
        tasks = [t for t in cells if families.get(t) == fam]
        row = {}
        for a in columns:
            rs = [cells[t].get(a) for t in tasks]
            if any(r is None or r["normalized_reward"]["mean"] is None
                   or r["normalized_cost"]["mean"] is None for r in rs):
                continue
            row[a] = {k: dict(mean=float(np.mean([r[k]["mean"] for r in rs])))
                      for k in ("normalized_reward", "normalized_cost")}
        out[f"{fam} average ({len(tasks)} task{'s' if len(tasks) > 1 else ''})"] = row
    return out


def results_table(cells: dict[str, dict[str, dict]], columns: Sequence[str] | None = None,
                  families: dict[str, str] | None = None) -> str:
    """Markdown table in the paper's Table 1 format: one row per task, a (reward, cost) column
    pair per algorithm.

    cells[task][algo] = results.json-like dict with `normalized_reward` / `normalized_cost`
    holding `mean` (None when every seed diverged) and `std`. Safe agents (cost < 1) are
    **bold**; among them the best reward is marked ★ and the second best ☆; unsafe entries
    are plain with † after the cost (the paper greys them; Markdown has no grey). A cell not
    run shows – (a partial table says so rather than leaving blanks). With `families`
    ({task: family}), one average row per family follows the tasks.
    """
    if columns is None:
        seen: list[str] = []
        for row in cells.values():
            seen += [a for a in row if a not in seen]
        columns = seen
    head = "| Task | " + " | ".join(f"{a} reward ↑ | {a} cost ↓" for a in columns) + " |"
    sep = "|---|" + "---|---|" * len(columns)
    lines = [head, sep]
    missing = False
    rows = dict(cells)
    if families:
        rows.update(_family_rows(cells, columns, families))
    for task, row in rows.items():
        marks = _cell_marks(row)
        parts = []
        for a in columns:
            r = row.get(a)
            if r is None:
                missing = True
                parts += ["–", "–"]
                continue
            nr, nc = r["normalized_reward"], r["normalized_cost"]
            if nr["mean"] is None or nc["mean"] is None:
                parts += ["n/a", "n/a"]
                continue
            std = ("std" in nr) and ("std" in nc)
            rs = _fmt(nr["mean"]) + (f" ± {_fmt(nr['std'])}" if std else "")
            cs = _fmt(nc["mean"]) + (f" ± {_fmt(nc['std'])}" if std else "")
            if _is_safe(r):
                rs, cs = f"**{rs}**", f"**{cs}**"
                if a in marks:
                    rs += f" {marks[a]}"
            else:
                cs += " †"
            parts += [rs, cs]
        name = task if task in cells else f"*{task}*"
        lines.append(f"| {name} | " + " | ".join(parts) + " |")
    lines.append("")
    lines.append("Mean ± std over seeds of the per-seed means over evaluation episodes. **Bold**: "
                 "safe (normalised cost < 1); ★ / ☆: the safe agents with the highest and "
                 "second-highest reward; †: unsafe." + (" Family rows average the tasks' means."
                                                         if families else "")
                 + (" –: no finished cell (not run; in a family row: not run, or diverged, on "
                    "one of the family's tasks); ★ / ☆ rank the cells present." if missing
                    else ""))
    return "\n".join(lines)


def plot_table(cells: dict[str, dict[str, dict]], columns: Sequence[str], path) -> Path:
    """Normalised reward against normalised cost, one panel per task, one marker per
    algorithm, the cost limit dashed (the table as a picture)."""
    plt = _plt()
    tasks = list(cells)
    ncol = min(4, len(tasks))
    nrow = (len(tasks) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.0 * nrow), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, t in enumerate(tasks):
        ax = axes[k // ncol][k % ncol]
        for j, a in enumerate(columns):
            r = cells[t].get(a)
            if r is None or r["normalized_cost"]["mean"] is None:
                continue
            nr, nc = r["normalized_reward"], r["normalized_cost"]
            ax.errorbar(nc["mean"], nr["mean"], xerr=nc.get("std", 0), yerr=nr.get("std", 0),
                        fmt="o", color=colors[j % len(colors)], label=a, capsize=2)
        ax.axvline(SAFE_LIMIT, color="red", ls="--", lw=1)
        ax.set_title(t, fontsize=9)
        ax.set_xlabel("normalised cost")
        ax.set_ylabel("normalised reward")
    for k in range(len(tasks), nrow * ncol):
        axes[k // ncol][k % ncol].axis("off")
    axes[0][0].legend(fontsize=7)
    out = _savefig(fig, path)
    plt.close(fig)
    return out


def _savefig(fig, path) -> Path:
    """Save a matplotlib figure atomically as PNG."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
    return Path(path)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_composition(returns: np.ndarray, costs: np.ndarray, kappa: float, path, title: str):
    """Per-trajectory cost vs return with the cost threshold (the paper's Figures 6-7)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 4))
    safe = costs <= kappa
    ax.scatter(costs[safe], returns[safe], s=6, c="tab:blue", label=f"safe ({safe.sum()})")
    ax.scatter(costs[~safe], returns[~safe], s=6, c="tab:orange", label=f"unsafe ({(~safe).sum()})")
    ax.axvline(kappa, color="red", ls="--", label=f"cost threshold {kappa:g}")
    ax.set_xlabel("episode cost")
    ax.set_ylabel("episode return")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    out = _savefig(fig, path)
    plt.close(fig)
    return out


def plot_curves(records: Iterable[dict], keys: Sequence[str], path, title: str = ""):
    """Training curves: records are JSONL rows with `step`, `lane` and the metric keys."""
    plt = _plt()
    rows = list(records)
    fig, axes = plt.subplots(1, len(keys), figsize=(4 * len(keys), 3.2), squeeze=False)
    for ax, key in zip(axes[0], keys):
        lanes = sorted({r.get("lane", 0) for r in rows if key in r})
        for lane in lanes:
            pts = [(r["step"], r[key]) for r in rows if r.get("lane", 0) == lane and key in r]
            if pts:
                xs, ys = zip(*pts)
                ax.plot(xs, ys, lw=1, label=f"lane {lane}")
        if key == "normalized_cost":
            ax.axhline(SAFE_LIMIT, color="red", ls="--", lw=0.8)
        ax.set_xlabel("gradient step")
        ax.set_title(key, fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    out = _savefig(fig, path)
    plt.close(fig)
    return out


def plot_run(logs, out_dir, title: str, metric_keys: Sequence[str]) -> None:
    """training.png (the given metric keys that were logged) and eval.png of a run directory."""
    out_dir = Path(out_dir)
    rows = logs.read("metrics")
    seen = {k for r in rows for k in r}
    keys = [k for k in metric_keys if k in seen]
    if keys:
        plot_curves(rows, keys, out_dir / "training.png", title)
    ev = logs.read("eval")
    if ev:
        seen = {k for r in ev for k in r}
        keys = ["normalized_reward", "normalized_cost"] + [k for k in EVAL_DIAGNOSTICS
                                                           if k in seen]
        plot_curves(ev, keys, out_dir / "eval.png", f"{title}: evaluation")


# Evaluation diagnostics plotted beside the scores where a run logged them (evaluate.py)
EVAL_DIAGNOSTICS = ("mean_length", "terminal_share", "not_first", "qr_given_up", "unsafe_state")


# What the project's own experiments found about a task's defaults, printed under the main
# job's table so that one table is not read as the verdict (a pointer, not a result of the run).
TASK_CONTEXT = {
    "ReachAvoid": (
        "the alpha x h grid on this data found h 7 / alpha 0.99 better for r2pac (0.83 reward, "
        "cost 0.07 on fresh seeds: experiments/reach_avoid/RESULTS.md, sections 6-7), a setting "
        "that did not transfer to the PPO-Lagrangian data (-0.12: experiments/data_factory/"
        "QUALITY_BAR.md); the registry's defaults are kept"),
}


def setting_line(cfg, task) -> str:
    """Which setting produced a run: the algorithm's task values against the registry's."""
    from r2pac_jax.agents import algo_module

    parts = [f"{cfg.algo}", f"{cfg.preset} preset", f"{cfg.seeds} seeds",
             f"{cfg.eval_episodes} evaluation episodes each"]
    named = []
    for key, reg in (("chunk_len", task.chunk_len), ("quantile_alpha", task.quantile_alpha),
                     ("penalty_c", task.penalty_c)):
        try:
            val = getattr(cfg, key)
        except AttributeError:
            continue
        if key in algo_module(cfg.algo).FIXED:
            continue  # pinned by the algorithm (a one-step method's h = 1)
        named.append(f"{key}={val:g}" + ("" if val == reg else f" (registry: {reg:g})"))
    head = parts.pop(0)
    if named:
        differs = any("registry" in n for n in named)
        head += (" with non-default values (" if differs else " at the registry's defaults (") \
            + ", ".join(named) + ")"
    return "Setting: " + ", ".join([head] + parts) + "."


def verdict_line(results: dict) -> str:
    """Which agents were safe and which safe agent had the best reward, from the results."""
    safe = {a: r["normalized_reward"]["mean"] for a, r in results.items() if _is_safe(r)}
    if not safe:
        return "No agent was safe (normalised cost < 1) on this data."
    best = max(safe, key=safe.get)
    return (f"Safe (normalised cost < 1): {', '.join(safe)}; the best safe reward: {best} "
            f"{safe[best]:.2f}.")
