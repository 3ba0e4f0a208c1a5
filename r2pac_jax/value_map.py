"""Value maps (the paper's Figures 3 and 8): a finished R2PAC run's state values over states
drawn from its data, the states embedded in 2-D and coloured by each value.

    python -m r2pac_jax.value_map RUN [--unpenalised RUN2] --dataset FILE [--states 5000]
        [--embedding umap|pca] --out DIR

R2PAC learns V_c and the penalised Vbar_r; the unpenalised V_r is the w/o-Vbar_r ablation's
(`r2pac-no-penalty`) value, read from a second run with `--unpenalised`. UMAP needs the
`analyses` extra (`pip install -e '.[analyses]'`); PCA is the substitute without it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.errors import R2pacError

R2PAC_FAMILY = ("r2pac", "r2pac-no-penalty", "r2pac-no-vc", "r2pac-awr", "r2pac-awr-flow",
                "r2pac-hj")


class ValueMapError(R2pacError, ValueError):
    pass


def restore_state(run_dir, log=lambda m: None):
    """(cfg, agent, state) of a run's newest readable checkpoint: every lane's whole training
    state ([L, ...] leaves), the critics included (the saved policy holds the target Q's only)."""
    from r2pac_jax.agents import algo_module
    from r2pac_jax.checkpoint import Checkpointer
    from r2pac_jax.loop import compiled
    from r2pac_jax.policy import read_run
    from r2pac_jax.tasks import get_task

    cfg, lanes = read_run(run_dir)
    if cfg.algo not in R2PAC_FAMILY:
        raise ValueMapError(f"{run_dir}: a {cfg.algo} run has no V_r / V_c to map; value maps "
                            f"read runs of {', '.join(R2PAC_FAMILY)}")
    task = get_task(cfg.task)
    agent, init, _, _ = compiled(cfg, task.obs_dim, task.act_dim)
    n = len(lanes["seeds"])
    hp = {k: jnp.zeros((n,), jnp.float32) for k in algo_module(cfg.algo).HPARAMS}
    like = jax.eval_shape(init, jnp.zeros((n, 2), jnp.uint32), hp)
    ckpt = Checkpointer(Path(run_dir) / "checkpoints")
    try:
        if ckpt.latest_step() is None:
            raise ValueMapError(f"{run_dir} holds no checkpoint: train it first (or --resume it)")
        step, state, _ = ckpt.restore_newest_readable(like, log=log)
    finally:
        ckpt.close()
    if step != cfg.total_steps:
        log(f"note: {run_dir} stopped at step {step} of {cfg.total_steps}; its values are "
            "those of that checkpoint")
    return cfg, agent, state


def state_values(run_dir, obs: np.ndarray, lane: int = 0) -> dict[str, np.ndarray]:
    """A run's state values at obs [N, O] for lane `lane`: {"V_c": [N], "Vbar_r": [N]} for a
    penalised run, {"V_c": [N], "V_r": [N]} for `r2pac-no-penalty` (its V_r is unpenalised)."""
    cfg, agent, state = restore_state(run_dir)
    n = jax.tree_util.tree_leaves(state.params)[0].shape[0]
    if not 0 <= lane < n:
        raise ValueMapError(f"lane {lane} out of range: {run_dir} has {n} lanes")
    if obs.ndim != 2 or obs.shape[1] != agent.obs_dim:
        raise ValueMapError(f"states of shape {obs.shape}; {cfg.task} needs [N, {agent.obs_dim}]")
    params = jax.tree_util.tree_map(lambda x: x[lane], state.params)
    x = jnp.asarray(obs, jnp.float32)
    vc = np.asarray(agent.vc_net.apply(params["vc"], x))
    vr = np.asarray(agent.v_net.apply(params["vr"], x))
    return {"V_c": vc, ("Vbar_r" if cfg.agent.reward_penalty else "V_r"): vr}


def sample_states(observations: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """n distinct rows of observations [T, O] (all of them where T <= n), numpy generator `seed`."""
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(len(observations), size=min(n, len(observations)), replace=False))
    return np.asarray(observations[idx], np.float32)


def embed(states: np.ndarray, method: str = "auto", seed: int = 0) -> tuple[np.ndarray, str]:
    """2-D coordinates [N, 2] of states [N, O] (standardised per dimension first), and the
    method used: UMAP (random_state=seed, one thread: deterministic) or PCA."""
    if method not in ("auto", "umap", "pca"):
        raise ValueMapError(f"unknown embedding {method!r}; choose umap, pca or auto")
    x = np.asarray(states, np.float64)
    x = (x - x.mean(0)) / np.where(x.std(0) > 1e-8, x.std(0), 1.0)
    if method in ("auto", "umap"):
        try:
            import umap
        except ImportError:
            if method == "umap":
                raise ValueMapError("UMAP is not installed: pip install -e '.[analyses]' (or "
                                    "choose --embedding pca)") from None
        else:
            reducer = umap.UMAP(n_components=2, random_state=seed, n_jobs=1)
            return np.asarray(reducer.fit_transform(x.astype(np.float32)), np.float64), "UMAP"
    _, _, vt = np.linalg.svd(x - x.mean(0), full_matrices=False)
    coords = x @ vt[:2].T
    coords *= np.where(coords[np.abs(coords).argmax(0), range(2)] < 0, -1.0, 1.0)  # fixed sign
    return coords, "PCA"


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation (ties take their mean rank)."""
    def ranks(x):
        order = np.argsort(x, kind="stable")
        r = np.empty(len(x))
        r[order] = np.arange(len(x), dtype=np.float64)
        _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
        sums = np.bincount(inv, weights=r)
        return sums[inv] / counts[inv]

    ra, rb = ranks(np.asarray(a)), ranks(np.asarray(b))
    if ra.std() == 0 or rb.std() == 0:
        return float("nan")
    return float(np.corrcoef(ra, rb)[0, 1])


ORDER = ("V_r", "V_c", "Vbar_r")


def value_map(states: np.ndarray, values: dict[str, np.ndarray], out_dir, name: str,
              title: str = "", method: str = "auto", seed: int = 0) -> dict:
    """OUT/NAME.csv (x, y and each value per state) and OUT/NAME.png (one panel per value);
    returns the method and the Spearman correlations of V_r and Vbar_r with V_c."""
    import csv
    import io

    from r2pac_jax.io import atomic_write_text
    from r2pac_jax.report import _plt, _savefig

    keys = [k for k in ORDER if k in values]
    for k in keys:
        if np.shape(values[k]) != (len(states),):
            raise ValueMapError(f"{k} has shape {np.shape(values[k])}; expected "
                                f"[{len(states)}], one value per state")
    coords, used = embed(states, method, seed)
    corr = {f"spearman_{k}_vs_V_c": spearman(values[k], values["V_c"])
            for k in ("V_r", "Vbar_r") if k in values and "V_c" in values}
    out_dir = Path(out_dir)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["x", "y"] + keys)
    for i in range(len(states)):
        w.writerow([f"{coords[i, 0]:.5g}", f"{coords[i, 1]:.5g}"]
                   + [f"{float(values[k][i]):.6g}" for k in keys])
    atomic_write_text(out_dir / f"{name}.csv", buf.getvalue())
    plt = _plt()
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 3.8), squeeze=False)
    for ax, k in zip(axes[0], keys):
        sc = ax.scatter(coords[:, 0], coords[:, 1], c=values[k], s=2, cmap="viridis",
                        rasterized=True)
        fig.colorbar(sc, ax=ax, shrink=0.8)
        sub = f" (Spearman with V_c {corr[f'spearman_{k}_vs_V_c']:+.2f})" \
            if f"spearman_{k}_vs_V_c" in corr else ""
        ax.set_title(k + sub, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{title} - {len(states)} data states, {used} embedding".strip(" -"),
                 fontsize=10)
    _savefig(fig, out_dir / f"{name}.png")
    plt.close(fig)
    return dict(embedding=used, states=len(states), **corr)


def main(argv: Optional[list] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.value_map", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", help="a finished run of r2pac or one of its variants")
    ap.add_argument("--unpenalised", help="a finished r2pac-no-penalty run on the same task: "
                    "its V_r is the unpenalised value")
    ap.add_argument("--dataset", required=True, help="the HDF5 file the states are drawn from")
    ap.add_argument("--states", type=int, default=5000)
    ap.add_argument("--lane", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0, help="draws the states and seeds UMAP")
    ap.add_argument("--embedding", default="auto", help="umap | pca | auto (UMAP if installed)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    from r2pac_jax.data import load_dsrl
    from r2pac_jax.policy import read_run
    from r2pac_jax.tasks import get_task

    try:
        if args.states < 2:
            raise ValueMapError(f"--states {args.states}: need at least 2 states")
        cfg, _ = read_run(args.run)
        task = get_task(cfg.task)
        ds = load_dsrl(args.dataset, task.obs_dim, task.act_dim, task.name)
        states = sample_states(np.asarray(ds.observations), args.states, args.seed)
        values = state_values(args.run, states, args.lane)
        if args.unpenalised:
            other, _ = read_run(args.unpenalised)
            if other.task != cfg.task or other.agent.reward_penalty:
                raise ValueMapError(f"--unpenalised {args.unpenalised}: needs an "
                                    f"r2pac-no-penalty run on {cfg.task}, got {other.algo} on "
                                    f"{other.task}")
            values["V_r"] = state_values(args.unpenalised, states, args.lane)["V_r"]
        info = value_map(states, values, args.out, cfg.task, f"{cfg.task} (lane {args.lane})",
                         args.embedding, args.seed)
    except (R2pacError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                   for k, v in info.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
