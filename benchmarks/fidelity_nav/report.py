"""Markdown tables of compare.py's JSON results (for benchmarks/FIDELITY.md).

    python benchmarks/fidelity_nav/report.py RESULTS.json [MORE.json or compare.log ...]

Several files (e.g. a C MuJoCo run and an MJX run) are merged task by task.
"""
from __future__ import annotations

import json
import sys


def _e(x) -> str:
    """A number in short scientific / fixed notation."""
    if x is None:
        return "-"
    if isinstance(x, bool):
        return str(x)
    if isinstance(x, int):
        return str(x)
    if x == 0:
        return "0"
    if abs(x) >= 0.01:
        return f"{x:.3g}"
    return f"{x:.1e}"


def _pct(x) -> str:
    return f"{100 * x:.1f}%"


def merge(paths) -> dict:
    """Results of several files, merged per task. A file is compare.py's --out JSON or its
    printed log (one JSON object per task and line; other lines are skipped)."""
    out: dict = {}
    for p in paths:
        with open(p) as f:
            text = f.read()
        try:
            parts = [json.loads(text)]
        except json.JSONDecodeError:
            parts = []
            for line in text.splitlines():
                if line.startswith("{"):
                    parts.append(json.loads(line))
        for part in parts:
            for task, res in part.items():
                out.setdefault(task, {}).update(res)
    return out


def tables(res: dict) -> str:
    lines = []
    add = lines.append
    exact = ("velocimeter", "gyro", "magnetometer", "ballangvel_rear", "ballquat_rear")
    for sfx, title in (("", "C MuJoCo 4.0 (float64)"), ("_mjx", "MJX (float32)")):
        rows = [(t, r["static" + sfx]) for t, r in res.items() if "static" + sfx in r]
        if not rows:
            continue
        add(f"\n**Observation and rules at the original's states, {title}**\n")
        add("| task | states | goals met | cost steps | lidars max err | other sensors max err "
            "| accelerometer err median / share > 1e-3 / after reset | reward, cost, goal_met "
            "agreement | reward max err |")
        add("|---|---|---|---|---|---|---|---|---|")
        for t, s in rows:
            o = s["obs_abs_err"]
            other = max(o[k]["max"] for k in exact if k in o)
            a = o["accelerometer"]
            ag = s["rules_agree"]
            add(f"| {t} | {s['steps']} | {s['goals_met']} | {s['cost_steps']} | "
                f"{_e(o['lidars']['max'])} | {_e(other)} | {_e(a['median'])} / "
                f"{_pct(a['frac_over_1em3'])} / {_e(a['reset_max'])} | "
                f"{_pct(ag['reward'])}, {_pct(ag['cost'])}, {_pct(ag['goal_met'])} | "
                f"{_e(s['rules_reward_max_abs_err'])} |")

    rows = [(t, r) for t, r in res.items() if "one_step" in r or "one_step_mjx" in r]
    if rows:
        add("\n**One control step from each of the original's states** (agent qpos max-abs "
            "error: median / p99 / max over steps; agent XY error p99 in m)\n")
        add("| task | steps | C MuJoCo: agent qpos | C: XY p99 | C: cost agreement | MJX: agent "
            "qpos | MJX: XY p99 | MJX vs C MuJoCo on the same (MJX) model: agent qpos |")
        add("|---|---|---|---|---|---|---|---|")
        for t, r in rows:
            c, m = r.get("one_step", {}), r.get("one_step_mjx", {})

            def q3(d, k):
                return " / ".join(_e(v) for v in d[k]) if k in d else "-"
            add(f"| {t} | {c.get('steps', m.get('steps'))} | {q3(c, 'agent_qpos_err')} | "
                f"{_e(c['agent_xy_err'][1]) if c else '-'} | "
                f"{_pct(c['cost_agree']) if c else '-'} | {q3(m, 'agent_qpos_err')} | "
                f"{_e(m['agent_xy_err'][1]) if m else '-'} | "
                f"{q3(m, 'agent_qpos_err_vs_c_mujoco_same_model')} |")

    rows = [(t, r["model"]) for t, r in res.items() if "model" in r]
    if rows:
        add("\n**Where one-step gaps come from** (C MuJoCo; agent qpos max-abs error per step, "
            "max or p99 / max over steps)\n")
        add("| task | ours vs their MJCF, both MuJoCo 4.0: max | their MJCF 4.0 vs 2.3.3: "
            "bit-exact share, p99 / max | accelerometer: ours vs their MJCF 4.0 max; 4.0 vs "
            "2.3.3 p99 / max | MJX variant vs exact model: share of steps with XY > 1e-6, XY "
            "p99 / max | touching states; lost by MJX variant |")
        add("|---|---|---|---|---|---|")
        for t, m in rows:
            v = m["their_mjcf_mujoco4_vs_mujoco233_agent_qpos"]
            acc_v = m["accelerometer_their_mjcf_mujoco4_vs_mujoco233"]
            xy = m["mjx_variant_vs_exact_agent_xy"]
            add(f"| {t} | {_e(m['ours_vs_their_mjcf_in_mujoco4_agent_qpos'][2])} | "
                f"{_pct(m['their_mjcf_mujoco4_vs_mujoco233_exact_frac'])}, {_e(v[1])} / "
                f"{_e(v[2])} | {_e(m['accelerometer_ours_vs_their_mjcf_mujoco4'][2])}; "
                f"{_e(acc_v[1])} / {_e(acc_v[2])} | "
                f"{_pct(m['mjx_variant_vs_exact_frac_steps_xy_over_1em6'])}, {_e(xy[1])} / "
                f"{_e(xy[2])} | {m['states_touching_cost_or_goal_objects']}; "
                f"{m['of_which_lost_in_mjx_variant']} |")

    for sfx, title in (("", "C MuJoCo"), ("_mjx", "MJX")):
        rows = [(t, r["open_loop" + sfx]) for t, r in res.items() if "open_loop" + sfx in r]
        if not rows:
            continue
        add(f"\n**Open loop, {title}**: the original's actions replayed from its state at step "
            "1; \"twin\" = the original itself after a 1e-9 velocity kick\n")
        add("| task | steps x episodes | first reward divergence (> 1e-3), per episode: ours; "
            "twin | reward agreement: ours; twin | cost agreement: ours; twin | agent XY drift "
            "at step 25 / 100 (m, median): ours; twin | returns ours / original |")
        add("|---|---|---|---|---|---|---|")
        for t, o in rows:
            d, td = o["agent_xy_drift"], o.get("twin_agent_xy_drift", {})
            add(f"| {t} | {o['steps']} x {o['episodes']} | {o['first_reward_divergence']}; "
                f"{o.get('twin_first_reward_divergence', '-')} | "
                f"{_pct(o['reward_within_1em3'])}; {_pct(o.get('twin_reward_within_1em3', 0))}"
                f" | {_pct(o['cost_agree'])}; {_pct(o.get('twin_cost_agree', 0))} | "
                f"{_e(d.get('25'))} / {_e(d.get('100'))}; {_e(td.get('25'))} / "
                f"{_e(td.get('100'))} | {o['return_ours']} / {o['return_ref']} |")

    rows = [(t, r["layouts"]) for t, r in res.items() if "layouts" in r]
    if rows:
        add("\n**Layouts** (n layouts from each sampler; KS p-values Bonferroni-corrected over "
            "the tests of the row)\n")
        add("| task | n | objects (per kind) | max diff of per-object mean / std of x, y | "
            "pairwise-distance deciles 10/50/90 ours; original | KS x, y worst (p) | KS per "
            "pair worst (p) | KS all pairs pooled | min clearance over keepout sums ours; "
            "original |")
        add("|---|---|---|---|---|---|---|---|---|")
        for t, lay in rows:
            counts = ", ".join(f"{k} {v}" for k, v in lay["counts"].items())
            add(f"| {t} | {lay['n']} | {counts} | {_e(lay['max_abs_diff_mean_xy'])} / "
                f"{_e(lay['max_abs_diff_std_xy'])} | {lay['pair_quantiles_ours']}; "
                f"{lay['pair_quantiles_ref']} | {_e(lay['ks_xy_worst'])} "
                f"({lay['ks_xy_worst_object']}, p {_e(lay['ks_xy_worst_pvalue_bonferroni'])}) | "
                f"{_e(lay['ks_pair_worst'])} (p {_e(lay['ks_pair_worst_pvalue_bonferroni'])}) |"
                f" {_e(lay['ks_all_pairwise_pooled'])} | {_e(lay['min_keepout_slack_ours'])}; "
                f"{_e(lay['min_keepout_slack_ref'])} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    paths = (argv if argv is not None else sys.argv[1:])
    if not paths:
        print(__doc__, file=sys.stderr)
        return 2
    print(tables(merge(paths)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
