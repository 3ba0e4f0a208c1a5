import pytest

from r2pac_jax.agents import algo_names
from r2pac_jax.config import ConfigError, make_config, resolve_preset
from r2pac_jax.tasks import UnknownTaskError, get_task, list_tasks


def test_task_table_values_reach_the_config():
    cfg = make_config("CarGoal2", "r2pac", "paper")
    assert (cfg.quantile_alpha, cfg.penalty_c, cfg.chunk_len, cfg.reward_scale) == (0.9, 10.0, 5, 200.0)
    assert cfg.steps == 600_000 and cfg.batch_size == 1024 and cfg.hidden_dims == (512,) * 4
    hc = make_config("HalfCheetahVelocity", "r2pac", "paper")
    assert (hc.quantile_alpha, hc.penalty_c, hc.chunk_len, hc.reward_scale) == (0.99, 1.0, 1, 1.0)
    assert make_config("BallRun", "r2pac", "paper").quantile_alpha == 0.5


def test_paper_table4_is_complete():
    table4 = {"AntRun": (.7, 1), "BallRun": (.5, 1), "CarRun": (.95, 1), "DroneRun": (.7, 1),
              "AntCircle": (.7, 1), "BallCircle": (.85, 1), "CarCircle": (.9, 1),
              "DroneCircle": (.7, 1), "CarPush1": (.9, 10), "CarPush2": (.9, 10),
              "CarGoal1": (.9, 10), "CarGoal2": (.9, 10), "CarButton1": (.8, 10),
              "CarButton2": (.5, 10), "AntVelocity": (.95, 1), "HalfCheetahVelocity": (.99, 1),
              "SwimmerVelocity": (.7, 1)}
    for name, (a, c) in table4.items():
        t = get_task(name)
        assert (t.quantile_alpha, t.penalty_c) == (a, c), name


def test_algo_switches():
    assert make_config("ReachAvoid", "r2pac-no-penalty").reward_penalty is False
    assert make_config("ReachAvoid", "r2pac-no-vc").unsafe_branch is False
    assert make_config("ReachAvoid", "r2pac-awr").actor == "awr_gaussian"
    assert make_config("ReachAvoid", "r2pac-awr-flow").actor == "awr_flow"
    assert make_config("ReachAvoid", "r2pac-hj").cost_critic == "hj"
    bc = make_config("ReachAvoid", "bc-safe")
    assert (bc.data_filter, bc.phases) == ("safe", ("actor",))
    assert set(algo_names()) >= {"r2pac", "bc-all", "bc-safe", "bc-all-mlp", "bc-safe-mlp"}


def test_dsrl_ids_resolve():
    assert get_task("OfflineCarGoal2Gymnasium-v0").name == "CarGoal2"
    assert get_task("SafetyAntVelocityGymnasium-v1").name == "AntVelocity"
    assert len(list_tasks()) >= 26


def test_bad_inputs_have_clear_errors():
    with pytest.raises(UnknownTaskError, match="unknown task 'CarGoal9'; known tasks: .*CarGoal2"):
        get_task("CarGoal9")
    with pytest.raises(ConfigError, match=r"quantile_alpha must lie in \(0, 1\), got 1.5"):
        make_config("ReachAvoid", overrides={"quantile_alpha": 1.5})
    with pytest.raises(ConfigError, match=r"quantile_alpha must lie in \(0, 1\), got 0.0"):
        make_config("ReachAvoid", overrides={"quantile_alpha": 0.0})
    with pytest.raises(ConfigError, match="chunk_len 81 is longer than an episode of ReachAvoid "
                                          r"\(80 steps\)"):
        make_config("ReachAvoid", overrides={"chunk_len": 81})
    with pytest.raises(ConfigError, match="unknown algo 'r2pack'"):
        make_config("ReachAvoid", "r2pack")
    with pytest.raises(ConfigError, match="unknown config key 'alpha'"):
        make_config("ReachAvoid", overrides={"alpha": 0.5})
    with pytest.raises(ConfigError, match="selection='best' is not one of"):
        make_config("ReachAvoid", overrides={"selection": "best"})
    with pytest.raises(ConfigError, match="unknown preset 'fast'"):
        make_config("ReachAvoid", preset="fast")
    with pytest.raises(ConfigError, match="must be a multiple of block_steps"):
        make_config("ReachAvoid", overrides={"steps": 750})


def test_auto_preset_says_what_it_chose():
    preset, why = resolve_preset("auto")
    import jax

    assert preset == ("quick" if jax.default_backend() == "cpu" else "paper")
    assert preset in why and "auto" in why


def test_cli_steps_shorter_than_the_block_fit_the_block():
    from r2pac_jax.planner import fit_blocks_to_steps

    over = dict(steps=200)
    fit_blocks_to_steps(over, "quick")
    cfg = make_config("ReachAvoid", "r2pac", "quick", over)  # would raise without the fit
    assert (cfg.steps, cfg.block_steps, cfg.eval_every, cfg.checkpoint_every) == (
        200, 100, 200, 200)
    explicit = dict(steps=200, block_steps=500)
    fit_blocks_to_steps(explicit, "quick")
    assert explicit == dict(steps=200, block_steps=500)  # the user's own value is kept
    with pytest.raises(ConfigError, match="must be a multiple of block_steps"):
        make_config("ReachAvoid", "r2pac", "quick", explicit)


def test_the_block_key_of_its_old_name():
    # a run's config.json written before the rename is read as the new key ...
    import json

    from r2pac_jax.config import Config, refuse_user_key

    cfg = make_config("ReachAvoid", overrides={"block_steps": 250, "steps": 1000})
    old = json.loads(cfg.to_json())
    old["threshold_every"] = old.pop("block_steps")
    assert Config.from_dict(old) == cfg
    # ... while a user who writes the old name is told the new one
    with pytest.raises(ConfigError, match="threshold_every is now called block_steps"):
        make_config("ReachAvoid", overrides={"threshold_every": 250})
    with pytest.raises(ConfigError, match="--set threshold_every=...: .* block_steps=..."):
        refuse_user_key("threshold_every", "--set")
