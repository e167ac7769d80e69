"""Configuration layers: defaults, files, --set overrides; unknown keys are errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuronsmae.trainers.cli import build_parser, config_from_args
from neuronsmae.trainers.config import (
    ConfigError,
    TrainConfig,
    field_docs,
    make_config,
    parse_overrides,
    preset,
    read_config_file,
)


def test_paper_preset_restores_the_papers_hyper_parameters() -> None:
    cfg = make_config(preset("paper"))
    assert (cfg.lr, cfg.gamma, cfg.eps_start, cfg.eps_end) == (5e-4, 0.99, 0.2, 0.05)
    assert (cfg.grad_clip, cfg.agent_hidden, cfg.mixer_embed) == (10.0, 128, 32)
    assert (cfg.target_update_interval, cfg.td_lambda, cfg.features) == (5, 0.0, "raw")
    assert cfg.augment == "none" and make_config().augment == "enemies,field,allies"
    args = build_parser().parse_args(["--preset", "paper", "--set", "lr=0.01"])
    assert config_from_args(args).lr == 0.01  # --set still wins over the preset
    with pytest.raises(ConfigError, match="valid: paper"):
        preset("fast")


def test_every_field_has_a_docstring() -> None:
    docs = field_docs()
    assert set(docs) == set(TrainConfig().to_dict())
    assert all(doc.strip() for doc in docs.values())


def test_set_overrides_are_typed() -> None:
    cfg = make_config(
        parse_overrides(["lr=1e-3", "batch_size=8", "double_q=false", "alg=qmix", "episodes=1e3"])
    )
    assert cfg.lr == 1e-3 and cfg.batch_size == 8 and cfg.double_q is False
    assert cfg.alg == "qmix" and cfg.episodes == 1000


@pytest.mark.parametrize(
    ("items", "message"),
    [
        (["learning_rate=1"], "unknown config key.*'learning_rate'.*valid:"),
        (["lr"], "key=value"),
        (["batch_size=big"], "batch_size expects int"),
        (["double_q=maybe"], "expects a bool"),
        (["alg=mappo"], "valid: iql, qmix, vdn"),
        (["level=expert"], "valid: easy, middle, hard"),
        (["batch_size=0"], "batch_size must be"),
        (["features=polar"], "valid: raw, relative"),
        (["features=raw"], "head='points' needs features in .*'relative'"),
    ],
)
def test_bad_overrides_are_errors(items: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        make_config(parse_overrides(items))


def test_unknown_key_suggests_the_close_one() -> None:
    with pytest.raises(ConfigError, match="did you mean 'batch_size'"):
        make_config({"batchsize": 3})


def test_files_toml_and_json(tmp_path: Path) -> None:
    toml = tmp_path / "c.toml"
    toml.write_text('[train]\nalg = "iql"\nlr = 0.001\nworkers = 3\n')
    assert read_config_file(toml) == {"alg": "iql", "lr": 0.001, "workers": 3}
    js = tmp_path / "c.json"
    js.write_text(json.dumps({"gamma": 0.9, "typo_key": 1}))
    with pytest.raises(ConfigError, match="typo_key"):
        read_config_file(js)
    with pytest.raises(ConfigError, match=r"\.toml or \.json"):
        read_config_file(tmp_path / "c.yaml")


def test_cli_layers_flags_win_over_set_and_file(tmp_path: Path) -> None:
    f = tmp_path / "c.json"
    f.write_text(json.dumps({"alg": "iql", "lr": 0.002, "seed": 4}))
    args = build_parser().parse_args(
        ["--config", str(f), "--set", "lr=0.003", "--alg", "qmix", "--level", "hard"]
    )
    cfg = config_from_args(args)
    assert (cfg.alg, cfg.level, cfg.lr, cfg.seed) == ("qmix", "hard", 0.003, 4)
    assert str(cfg.run_dir) == "runs/qmix_hard_s4"


def test_resume_without_a_run_is_an_error(tmp_path: Path) -> None:
    args = build_parser().parse_args(["--resume", "--out", str(tmp_path / "none")])
    with pytest.raises(ConfigError, match="--resume"):
        config_from_args(args)


def test_learning_rate_must_be_positive() -> None:
    with pytest.raises(ConfigError, match="lr must be > 0"):
        TrainConfig(lr=0.0)


def test_the_readme_main_job_is_the_target_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """``neuronsmae-train --alg vdn --level easy`` trains exactly as the benchmark's target run
    (``bench/bench_learning.py`` with its defaults: 30 minutes, two workers, validation every
    500 episodes on 50, a 200-episode test), so the README's figure is what a user gets."""
    from bench.bench_learning import bench_config
    from bench.bench_learning import parse_args as bench_args

    main_job = config_from_args(build_parser().parse_args(["--alg", "vdn", "--level", "easy"]))
    target = bench_config(bench_args([]), Path("runs/x"))
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    assert main_job.n_workers() == target.n_workers() == 2
    assert main_job.episodes >= 20_000  # never the binding budget in 30 minutes on 2 cores
    ignored = {"out", "progress", "episodes", "workers"}
    wanted = target.to_dict()
    differ = {
        k: (v, wanted[k])
        for k, v in main_job.to_dict().items()
        if k not in ignored and v != wanted[k]
    }
    assert differ == {}


@pytest.mark.parametrize(("cores", "workers"), [(1, 2), (2, 2), (4, 3), (24, 23)])
def test_default_workers_are_cores_less_one_and_at_least_two(
    monkeypatch: pytest.MonkeyPatch, cores: int, workers: int
) -> None:
    monkeypatch.setattr("os.cpu_count", lambda: cores)
    assert make_config({}).n_workers() == workers
    assert make_config({"workers": 5}).n_workers() == 5
