"""core.batch: the --list file, and which share of a batch one process of a torchrun/accelerate run takes."""

import pytest

from scpainter_blender.core import batch_items as batch, errors


def test_ranks_from_the_environment(monkeypatch):
    for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK"):
        monkeypatch.delenv(name, raising=False)
    assert batch.ranks_from_env() == (0, 1, 0)
    monkeypatch.setenv("RANK", "3")
    monkeypatch.setenv("WORLD_SIZE", "4")
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert batch.ranks_from_env() == (3, 4, 1)


@pytest.mark.parametrize("env,field", [
    ({"RANK": "abc"}, "RANK"),
    ({"WORLD_SIZE": "0"}, "WORLD_SIZE"),
    ({"RANK": "2", "WORLD_SIZE": "2"}, "RANK"),         # a rank outside the world
    ({"WORLD_SIZE": "2"}, "RANK"),                       # every process would take rank 0's share
    ({"LOCAL_RANK": "-1"}, "LOCAL_RANK"),
])
def test_a_half_set_environment_is_bad_input(monkeypatch, env, field):
    for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK"):
        monkeypatch.delenv(name, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    with pytest.raises(errors.InputError) as e:
        batch.ranks_from_env()
    assert e.value.path == "(environment)" and e.value.field == field


def test_list_file(tmp_path):
    p = tmp_path / "jobs.txt"
    p.write_text("# scenes\na/job.json\n\n/abs/job.json\n")
    assert batch.read_list(p) == [str(tmp_path / "a" / "job.json"), "/abs/job.json"]
    p.write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(errors.InputError, match="not UTF-8"):
        batch.read_list(p)


def test_ray_options_are_checked_before_any_work():
    batch.check_ray_options(0, 0.5)
    batch.check_ray_options(batch.MAX_RETRIES, 64)
    for retries, cpus, field in ((-1, 1.0, "--retries"), (batch.MAX_RETRIES + 1, 1.0, "--retries"),
                                 (1.5, 1.0, "--retries"), (2, 0.0, "--cpus-per-job"), (2, -1, "--cpus-per-job"),
                                 (2, float("inf"), "--cpus-per-job"), (2, float("nan"), "--cpus-per-job")):
        with pytest.raises(errors.ArgumentError) as e:
            batch.check_ray_options(retries, cpus)
        assert e.value.path == errors.COMMAND_LINE and e.value.field == field


def test_ray_options_default_when_not_given_and_are_refused_without_ray():
    assert batch.ray_options("", None, None) == (batch.DEFAULT_RETRIES, batch.DEFAULT_CPUS_PER_JOB)
    assert batch.ray_options("head:6379", 0, 2.0) == (0, 2.0) and batch.ray_options(None) == (
        batch.DEFAULT_RETRIES, batch.DEFAULT_CPUS_PER_JOB)
    for retries, cpus, field in ((3, None, "--retries"), (None, 2.0, "--cpus-per-job")):  # would be ignored
        with pytest.raises(errors.ArgumentError, match="applies to --ray only") as e:
            batch.ray_options(None, retries, cpus)
        assert e.value.field == field
    with pytest.raises(errors.ArgumentError) as e:       # checked with --ray
        batch.ray_options("", -1, None)
    assert e.value.field == "--retries"


def test_status_counts_in_the_order_first_met():
    results = [{"status": "ok"}, {"status": "failed"}, {"status": "ok"}, {"status": "not run (SIGTERM)"}]
    counts = batch.status_counts(results)
    assert counts == {"ok": 2, "failed": 1, "not run (SIGTERM)": 1} and list(counts) == ["ok", "failed",
                                                                                         "not run (SIGTERM)"]
    assert batch.status_counts([]) == {}


def test_shard_option_is_one_rule_for_both_batch_commands():
    assert batch.shard_option(None, None) is None and batch.shard_option("", "") is None
    assert batch.shard_option("1/4", None) == (1, 4) and batch.parse_shard("0/1") == (0, 1)
    for text, ray in (("2/2", None), ("x", None), ("1/2/3", None), ("-1/2", None), ("0/2", ""), ("0/2", "head:6379")):
        with pytest.raises(errors.ArgumentError) as e:
            batch.shard_option(text, ray)
        assert e.value.field == "--shard", (text, ray)
