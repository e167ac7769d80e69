"""Configuration layers: defaults, files, --set overrides; unknown keys are errors."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from neuronsmae.trainers.run import config
from neuronsmae.trainers.run.cli import build_parser, config_from_args, main
from neuronsmae.trainers.run.config import (
    GROUPS,
    KEYS,
    ConfigError,
    LearnerConfig,
    TrainConfig,
    field_docs,
    make_config,
    parse_overrides,
    preset,
    read_config_file,
)


def test_the_configuration_is_grouped_and_small() -> None:
    top = [f.name for f in dataclasses.fields(TrainConfig)]
    assert len(top) < 35 and set(GROUPS) <= set(top)
    sizes = {name: len(dataclasses.fields(cls)) for name, cls in GROUPS.items()}
    assert sizes == {
        "learner": 35, "eval": 10, "cluster": 10, "arena": 9, "selfplay": 2, "experimental": 3
    }  # fmt: skip
    assert len(KEYS) == len(top) - len(GROUPS) + sum(sizes.values())


def test_a_preset_is_a_layer_under_set() -> None:
    args = build_parser().parse_args(["--preset", "paper", "--set", "lr=0.01"])
    assert config_from_args(args).learner.lr == 0.01  # --set still wins over the preset
    assert make_config().learner.augment == "auto"  # every symmetry the task has
    with pytest.raises(ConfigError, match="valid: paper"):
        preset("fast")


def test_every_key_has_a_docstring() -> None:
    docs = field_docs()
    assert list(docs) == list(KEYS)
    assert all(doc.strip() for doc in docs.values())
    assert "learner.lr" in docs and "experimental.start_replay" in docs


def test_set_overrides_are_typed_and_bare_names_find_their_group() -> None:
    cfg = make_config(
        parse_overrides(
            ["learner.lr=1e-3", "batch_size=8", "double_q=false", "alg=qmix", "episodes=1e3"]
        )
    )
    assert cfg.learner.lr == 1e-3 and cfg.learner.batch_size == 8
    assert cfg.learner.double_q is False and cfg.alg == "qmix" and cfg.episodes == 1000
    assert parse_overrides(["eval_every=3", "cluster.router=tcp/h:7447"]) == {
        "eval.eval_every": "3",
        "cluster.router": "tcp/h:7447",
    }


@pytest.mark.parametrize(
    ("items", "message"),
    [
        (["learning_rate=1"], "unknown config key 'learning_rate'.*valid: alg, level"),
        (["lr"], "key=value"),
        (["batch_size=big"], "learner.batch_size expects int"),
        (["double_q=maybe"], "expects a bool"),
        (["alg=mappo"], "valid: iql, qmix, vdn"),
        (["level=expert"], "valid: 0, 1, easy, middle, hard, random"),
        (["batch_size=0"], "batch_size must be"),
        (["features=polar"], "valid: raw, relative"),
        (["features=raw", "head=points"], "head='points' needs features in .*'relative'"),
        (["arena.action_space=continuous"], "Q-learners .*valid: abstract, discrete"),
        (["n_blue=4"], "arena.n_blue must be in"),
        (["arena.options=mode=bots"], "arena.options sets \\['mode'\\]"),
        (["opponent=expert"], "opponent entry 'expert'"),
        (["learner=3"], "a group: set learner.<name>"),
        (["eval.lr=1"], "unknown config key 'eval.lr'"),
        (["servers=cloud"], "valid: local, actors"),
        (["cluster.groups=0"], "groups must be ≥ 1"),
        (["groups=3", "envs_per_worker=2"], r"cluster.groups must be in \[1, envs_per_worker=2\]"),
        (["servers_per_worker=0"], "servers_per_worker must be ≥ 1"),
        (
            ["servers_per_worker=3", "envs_per_worker=2"],
            r"cluster.servers_per_worker must be in \[1, envs_per_worker=2\]",
        ),
        (["servers_per_worker=2", "base_port=12000"], "needs private servers"),
        (["servers_per_worker=2", "servers=actors"], "needs private servers"),
        (["lr=nan"], "lr must be a finite number, got nan"),
        (["max_minutes=nan"], "max_minutes must be a finite number, got nan"),
        (["max_minutes=inf"], "max_minutes must be a finite number, got inf"),
        (["worker_cpus=nan"], "worker_cpus must be a finite number, got nan"),
        (["grad_clip=0"], "grad_clip must be > 0, got 0.0"),
        (["gamma=nan"], "gamma must be a finite number, got nan"),
        (["worker_resources=big=nan"], "expected a custom name and an amount > 0"),
        (["eps_anneal_episodes=-1"], "eps_anneal_episodes must be ≥ 0, got -1"),
        (["env=inprocess", "base_port=12000"], "cluster.base_port applies only to env=remote"),
        (
            ["env=inprocess", "servers=actors", "router=tcp/h:7447"],
            "cluster.servers, cluster.router apply only to env=remote",
        ),
        (["base_port=65535", "workers=3"], "base_port=65535 with 3 workers needs ports up to"),
        (
            ["arena.options=k=6;coef=2"],
            r"arena.options sets unknown option\(s\) \['coef'\]; valid:",
        ),
        (["opponent=" + "x" * 5000], "opponent entry 'xxx"),
        (["eval_seed=0"], r"eval_seed must be in \[1, 9223372036844775607\]"),
        (["eval_seed=9223372036844775608"], r"eval_seed must be in \[1, 9223372036844775607\]"),
        (["eval_every=-1"], "eval_every must be ≥ 0, got -1"),
        (["learning_starts=-1"], "learning_starts must be ≥ 0, got -1"),
        (["agent_hidden=4097"], r"agent_hidden must be in \[1, 4096\], got 4097"),
        (["hypernet_hidden=100000"], r"hypernet_hidden must be in \[1, 4096\]"),
        (["buffer_size=10", "batch_size=11"], r"batch_size must be in \[1, buffer_size=10\]"),
        # the learner never trained: the buffer cannot hold that many episodes
        (
            ["buffer_size=2", "batch_size=1", "learning_starts=3"],
            r"learning_starts must be in \[0, buffer_size=2\], got 3",
        ),
    ],
)
def test_bad_overrides_are_errors(items: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        make_config(parse_overrides(items))


def test_unknown_key_suggests_the_close_one() -> None:
    with pytest.raises(ConfigError, match="did you mean 'batch_size'"):
        make_config({"batchsize": 3})
    with pytest.raises(ConfigError, match=re.escape("did you mean 'learner.batch_size'")):
        make_config({"learner.batchsize": 3})


def test_a_bare_name_in_two_groups_is_ambiguous(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(config.KEYS, "eval.lr", float)
    with pytest.raises(ConfigError, match=re.escape("ambiguous: use one of ['learner.lr'")):
        parse_overrides(["lr=0.1"])
    assert parse_overrides(["learner.lr=0.1"]) == {"learner.lr": "0.1"}


def test_files_with_tables_dotted_and_bare_keys(tmp_path: Path) -> None:
    toml = tmp_path / "c.toml"
    toml.write_text('alg = "iql"\nworkers = 3\n[learner]\nlr = 0.001\n[eval]\neval_every = 7\n')
    expected = {"alg": "iql", "workers": 3, "learner.lr": 0.001, "eval.eval_every": 7}
    assert read_config_file(toml) == expected
    wrapped = tmp_path / "w.toml"
    wrapped.write_text('[train]\nalg = "iql"\nlr = 0.001\n')
    assert read_config_file(wrapped) == {"alg": "iql", "learner.lr": 0.001}
    js = tmp_path / "c.json"
    js.write_text(json.dumps({"learner.gamma": 0.9, "cluster": {"worker_cpus": 1}}))
    assert make_config(read_config_file(js)).learner.gamma == 0.9
    js.write_text(json.dumps({"gamma": 0.9, "typo_key": 1}))
    with pytest.raises(ConfigError, match="typo_key"):
        read_config_file(js)
    with pytest.raises(ConfigError, match=r"\.toml or \.json"):
        read_config_file(tmp_path / "c.yaml")


@pytest.mark.parametrize(
    ("name", "text", "said"),
    [
        ("bad.toml", "[learner\n", "is not valid TOML: Expected ']'"),
        ("bad.json", "{not json", "is not valid JSON: Expecting property name"),
        ("list.json", "[1, 2]", "must hold a table of config keys, got list"),
        ("text.json", '"lr"', "must hold a table of config keys, got str"),
        ("binary.toml", b"\xff\xfe", "is not valid TOML"),
    ],
)
def test_a_malformed_config_file_is_a_config_error_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, text: str | bytes, said: str
) -> None:
    """These were a tomllib/json traceback or an AttributeError."""
    f = tmp_path / name
    f.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ConfigError, match=re.escape(f"config file {f} {said}")):
        read_config_file(f)
    assert main(["--config", str(f), "--episodes", "1"]) == 2
    assert f"config file {f}" in capsys.readouterr().err


@pytest.mark.parametrize("seed", [-1, 2**32])
def test_a_run_seed_outside_its_range_is_refused_before_training(
    seed: int, capsys: pytest.CaptureFixture[str]
) -> None:
    """A negative seed ended in NumPy's ValueError once Ray and the workers had started."""
    with pytest.raises(ConfigError, match=r"seed must be in \[0, 4294967295\]"):
        make_config({"seed": seed})
    assert main(["--seed", str(seed), "--episodes", "1"]) == 2
    assert "seed must be in [0, 4294967295]" in capsys.readouterr().err
    assert make_config({"seed": 2**32 - 1}).seed == 2**32 - 1


def test_a_cluster_router_that_is_no_locator_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"cluster\.router must be a Zenoh locator"):
        make_config({"router": "10.0.0.1:7447"})
    assert make_config({"router": "tls/10.0.0.1:7447"}).cluster.router == "tls/10.0.0.1:7447"


def test_an_address_where_nothing_listens_is_refused_at_once() -> None:
    """ray.init kept retrying such an address for over five minutes."""
    import socket

    from neuronsmae.trainers.run.placement import check_reachable

    with socket.socket() as probe:  # a port that was free a moment ago: nothing listens
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}"):
        with pytest.raises(ConfigError, match="nothing accepts connections there"):
            check_reachable(address)
    for address in ("nohost", "host:", "host:99999", "host:port"):
        with pytest.raises(ConfigError, match="must be 'auto', host:port or ray://host:port"):
            check_reachable(address)
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        check_reachable(f"127.0.0.1:{server.getsockname()[1]}")


def test_the_saved_config_is_nested_and_reads_back(tmp_path: Path) -> None:
    cfg = make_config({"alg": "qmix", "lr": 2e-3, "start_replay": 0.5, "address": "auto"})
    saved = json.loads(json.dumps(cfg.to_dict()))
    assert saved["learner"]["lr"] == 2e-3 and saved["experimental"]["start_replay"] == 0.5
    assert saved["cluster"]["address"] == "auto" and "lr" not in saved
    assert make_config(saved) == cfg


def test_an_out_that_is_a_file_is_refused_before_training(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    taken = tmp_path / "taken"
    taken.write_text("a file")
    assert main(["--out", str(taken), "--episodes", "1"]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err


def test_a_new_run_is_refused_a_directory_holding_another_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Running the same command twice overwrote the first run's config and checkpoint and
    appended its episodes to the same CSV files under the same episode numbers."""
    from neuronsmae.trainers.core.checkpoint import CHECKPOINT_NAME
    from neuronsmae.trainers.run.records import RUN_FILES, check_new_run_dir
    from neuronsmae.trainers.run.saving import BEST_NAME

    assert {CHECKPOINT_NAME, BEST_NAME} <= set(RUN_FILES)
    check_new_run_dir(tmp_path / "absent")
    check_new_run_dir(tmp_path)  # an empty folder, or one holding other things, is fine
    (tmp_path / "notes.txt").write_text("mine")
    check_new_run_dir(tmp_path)
    (tmp_path / "episodes.csv").write_text("episode\n1\n")
    assert main(["--out", str(tmp_path), "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path} already holds a run (episodes.csv): pass --resume to continue" in err
    assert (tmp_path / "episodes.csv").read_text() == "episode\n1\n"


def test_cli_layers_flags_win_over_set_and_file(tmp_path: Path) -> None:
    f = tmp_path / "c.json"
    f.write_text(json.dumps({"alg": "iql", "lr": 0.002, "seed": 4}))
    args = build_parser().parse_args(
        ["--config", str(f), "--set", "lr=0.003", "--alg", "qmix", "--level", "hard"]
    )
    cfg = config_from_args(args)
    assert (cfg.alg, cfg.level, cfg.learner.lr, cfg.seed) == ("qmix", "hard", 0.003, 4)
    assert str(cfg.run_dir) == "runs/qmix_hard_s4"
    address = config_from_args(build_parser().parse_args(["--address", "auto"]))
    assert address.cluster.address == "auto"


def test_resume_reads_the_saved_config(tmp_path: Path) -> None:
    args = build_parser().parse_args(["--resume", "--out", str(tmp_path / "none")])
    with pytest.raises(ConfigError, match="--resume"):
        config_from_args(args)
    saved = make_config({"out": str(tmp_path), "agent_hidden": 16, "alg": "iql"})
    (tmp_path / "config.json").write_text(json.dumps(saved.to_dict()))
    (tmp_path / "checkpoint.pt").write_bytes(b"")  # read only once the run starts
    args = build_parser().parse_args(["--resume", "--out", str(tmp_path), "--episodes", "9"])
    resumed = config_from_args(args)
    assert resumed.learner.agent_hidden == 16 and resumed.alg == "iql"
    assert resumed.episodes == 9


def test_help_config_lists_every_key_by_group(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help-config"]) == 0
    out = capsys.readouterr().out
    assert out.index("[top level]") < out.index("[learner]") < out.index("[experimental]")
    for key in KEYS:
        assert f"\n{key} = " in out, key
    assert "learner.lr = 0.0005\n    Adam learning rate" in out


def test_values_out_of_range_are_errors() -> None:
    with pytest.raises(ConfigError, match="lr must be > 0"):
        LearnerConfig(lr=0.0)
    with pytest.raises(ConfigError, match="gamma must lie in"):
        make_config({"gamma": 1.5})
    with pytest.raises(ConfigError, match="learner expects LearnerConfig"):
        TrainConfig(learner={"lr": 1.0})  # type: ignore[arg-type]


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


@pytest.mark.parametrize(
    ("layer", "message"),
    [
        ({"contexts": "coef"}, "not key=value"),
        ({"contexts": "coef=1;coef=2"}, "given twice"),
        ({"contexts": "Friction_coeff=0.7..0.3"}, "low > high"),
        ({"contexts": "coef=big"}, "not a number"),
        ({"eval.eval_contexts": "coef=0.5,1"}, "must be fixed"),
        ({"eval.extra_test_contexts": "coef=1|coef=0..1"}, "must be fixed"),
        ({"eval.extra_test_contexts": "coef=1.5|coef=1.5"}, "given once"),  # collapsed to one
        ({"eval.extra_test_contexts": "||"}, "not be empty"),
        ({"level": "2"}, "level='2' is not valid"),
        ({"iteration_episodes": -1}, "iteration_episodes"),
        ({"learner.prefetch": "sometimes"}, "prefetch='sometimes' is not valid; valid: auto, on"),
    ],
)
def test_bad_contexts_and_levels_are_config_errors(layer: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        make_config(layer)


@pytest.mark.parametrize("workers", [20, 25])
@pytest.mark.parametrize("servers", ["local", "actors"])
def test_a_local_ray_is_told_enough_cpus_for_every_worker_and_server(
    workers: int, servers: str
) -> None:
    from neuronsmae.trainers.run.placement import SERVER_CPUS, local_cpus

    cfg = make_config({"workers": workers, "env": "remote", "cluster": {"servers": servers}})
    need = workers * cfg.cluster.worker_cpus + (workers * SERVER_CPUS if servers == "actors" else 0)
    assert local_cpus(cfg) >= need + 1  # every worker and server actor placed, and the learner


@pytest.mark.parametrize("extra", [{"workers": 100_000}, {"workers": 2, "worker_cpus": 1e6}])
def test_a_local_ray_is_not_told_of_thousands_of_cpus(
    extra: dict[str, float], monkeypatch: pytest.MonkeyPatch
) -> None:
    from neuronsmae.trainers.run.placement import local_cpus

    monkeypatch.setattr("os.cpu_count", lambda: 2)
    # --workers 100000 started a local Ray of 50,001 CPUs and 100,000 actors on 2 cores
    with pytest.raises(ConfigError, match="a local Ray on this 2-core machine shares at most 64"):
        local_cpus(make_config(extra))


def test_a_bad_checkpoint_or_cluster_is_reported_without_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """What only starting the run finds (an opponent or resumed checkpoint that is no
    checkpoint, a cluster address nothing answers at, workers the cluster cannot place)
    ends the command with status 2 and the message, not a traceback."""
    from neuronsmae.trainers.core.checkpoint import CheckpointError
    from neuronsmae.trainers.run import train as train_module
    from neuronsmae.trainers.run.sampler import PlacementError

    for error in (
        CheckpointError("x.pt is not a NeuronsMAE checkpoint"),
        ConfigError("no Ray"),
        PlacementError("2 rollout workers cannot be placed"),
    ):

        def refuse(*args: object, error: Exception = error, **kwargs: object) -> None:
            raise error

        monkeypatch.setattr(train_module, "train", refuse)
        assert main(["--out", str(tmp_path / "run"), "--episodes", "1"]) == 2
        assert str(error) in capsys.readouterr().err


def test_more_torch_threads_than_cores_is_refused_before_ray_starts(tmp_path: Path) -> None:
    """100,000 threads made Ray's own start time out, with a traceback naming neither."""
    import os

    from neuronsmae.trainers.run.train import Trainer

    cores = os.cpu_count() or 1
    cfg = make_config({"torch_threads": cores + 1, "out": str(tmp_path / "run")})
    with pytest.raises(ConfigError, match=f"torch_threads={cores + 1}: .* give 1 to {cores}"):
        Trainer(cfg)
    assert not (tmp_path / "run").exists()


def test_resume_refuses_settings_that_change_the_networks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--resume --alg qmix on a VDN run was torch's 'Missing key(s) in state_dict' traceback,
    after Ray and the workers had started."""
    from neuronsmae.trainers.run.config import FIXED_ON_RESUME, check_resumable

    saved = make_config({"alg": "vdn", "out": str(tmp_path)})
    (tmp_path / "config.json").write_text(json.dumps(saved.to_dict()))
    (tmp_path / "checkpoint.pt").write_bytes(b"")  # read only once the run starts
    argv = ["--resume", "--out", str(tmp_path), "--episodes", "1"]
    for extra, said in (
        (["--alg", "qmix"], "this changes alg 'vdn' -> 'qmix'"),
        (["--set", "agent_hidden=64"], "learner.agent_hidden 128 -> 64"),
        (["--set", "n_blue=3", "--set", "n_red=3"], "arena.n_blue 2 -> 3; arena.n_red 2 -> 3"),
    ):
        assert main([*argv, *extra]) == 2
        assert said in capsys.readouterr().err
    # What does not shape the networks may change: the opponent, the budget, the reward.
    check_resumable(saved, make_config(saved.to_dict(), {"level": "hard", "reward": "sparse"}))
    assert all(key in KEYS for key in FIXED_ON_RESUME)


def test_resume_without_a_checkpoint_says_so_before_training(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run stopped before its first checkpoint: --resume was a FileNotFoundError traceback
    after Ray had started."""
    from neuronsmae.trainers.core.checkpoint import MissingCheckpointError, load_checkpoint

    (tmp_path / "config.json").write_text(json.dumps(make_config({}).to_dict()))
    assert main(["--resume", "--out", str(tmp_path), "--episodes", "1"]) == 2
    assert "holds no checkpoint.pt (the run stopped before its first one)" in (
        capsys.readouterr().err
    )
    with pytest.raises(MissingCheckpointError, match="no checkpoint at") as caught:
        load_checkpoint(tmp_path)
    assert isinstance(caught.value, FileNotFoundError)  # what callers caught before


@pytest.mark.parametrize("value", ["2.5e0", "1e400", "-1e400"])
def test_an_integer_in_scientific_notation_must_be_whole(value: str) -> None:
    # 2.5e0 became 2, and 1e400 an OverflowError traceback
    with pytest.raises(ConfigError, match=f"episodes expects a whole number, got '{value}'"):
        make_config(parse_overrides([f"episodes={value}"]))
    assert make_config(parse_overrides(["episodes=3e4"])).episodes == 30_000


@pytest.mark.parametrize(
    ("text", "said"),
    [("not json", "is not the JSON a run writes"), ("[]", "must hold a table of config keys"),
     ('{"bogus": 1}', "unknown config key 'bogus'")],
)  # fmt: skip
def test_resume_names_a_saved_config_it_cannot_read(
    text: str, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "config.json").write_text(text)  # was a JSONDecodeError / AttributeError
    (tmp_path / "checkpoint.pt").write_bytes(b"")
    assert main(["--resume", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"--resume: {tmp_path / 'config.json'}" in err and said in err


def test_an_out_that_cannot_be_a_directory_is_refused_before_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "file").write_text("")
    # a NotADirectoryError traceback once Ray and the workers had started
    assert main(["--out", str(tmp_path / "file" / "sub"), "--episodes", "1"]) == 2
    assert "cannot be created: Not a directory" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("fields", "said"),
    [({"progress": "no"}, "progress expects bool, got 'no' (str)"),  # the bar came on
     ({"episodes": 4.5}, "episodes expects int, got 4.5"),
     ({"seed": "1"}, "seed expects int, got '1'"),  # a TypeError inside a range check
     ({"out": 5}, "out expects str, got 5")],
)  # fmt: skip
def test_a_config_built_directly_is_checked_like_make_config(fields: dict, said: str) -> None:
    from neuronsmae.trainers.run.config import TrainConfig

    with pytest.raises(ConfigError, match=re.escape(said)):
        TrainConfig(**fields)
    with pytest.raises(ConfigError, match=re.escape(said)):
        dataclasses.replace(make_config({}), **fields)


def test_numpy_numbers_and_paths_are_taken_as_plain_values() -> None:
    import numpy as np

    cfg = dataclasses.replace(make_config({"lr": np.float32(1e-3), "episodes": np.int64(9)}),
                              out=Path("runs") / "x")  # fmt: skip
    assert (cfg.episodes, cfg.out) == (9, "runs/x") and type(cfg.learner.lr) is float
    assert json.loads(json.dumps(cfg.to_dict()))["out"] == "runs/x"  # config.json is written


@pytest.mark.parametrize(
    ("layers", "base", "said"),
    [((None,), None, "layer 0 must be a mapping of config keys, got NoneType"),
     (({}, [1]), None, "layer 1 must be a mapping"),
     (({},), {"lr": 1}, "base must be a TrainConfig, got dict")],
)  # fmt: skip
def test_make_config_names_a_layer_that_is_no_mapping(
    layers: tuple, base: object, said: str
) -> None:
    with pytest.raises(ConfigError, match=re.escape(said)):
        make_config(*layers, base=base)  # type: ignore[arg-type]
