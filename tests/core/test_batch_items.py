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


def test_a_job_list_may_declare_its_data_roots(tmp_path):
    """read_job_list: data-root: lines before the first path (relative to the list's folder) are folders the
    list's jobs may lead into; read_list (a list that declares nothing) refuses them, naming the line."""
    (tmp_path / "shared").mkdir()
    (tmp_path / "more").mkdir()
    p = tmp_path / "jobs.txt"
    p.write_text("# variants of one recording\ndata-root: shared\n\ndata-root:  " + str(tmp_path / "more")
                 + "\nv1/job.json\n/abs/job.json\n")
    listed = batch.read_job_list(p)
    assert listed.paths == [str(tmp_path / "v1" / "job.json"), "/abs/job.json"]
    assert listed.data_roots == (str(tmp_path / "shared"), str(tmp_path / "more"))
    assert batch.read_job_list(tmp_path / "jobs.txt").path == str(p)
    with pytest.raises(errors.InputError) as e:
        batch.read_list(p)
    assert e.value.path == str(p) and e.value.field == "line 2" and "--data-root" in e.value.hint
    (tmp_path / "afile").write_text("")
    for text, field, what in (("v1/job.json\ndata-root: shared\n", "line 2", "after the first path"),
                              ("data-root: missing\nv1/job.json\n", "line 1", "does not exist"),
                              ("# c\ndata-root: afile\n", "line 2", "is not a folder"),
                              ("data-root:\n", "line 1", "names no folder")):
        p.write_text(text)
        with pytest.raises(errors.InputError) as e:
            batch.read_job_list(p)
        assert e.value.path == str(p) and e.value.field == field and what in e.value.message, e.value


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


def test_items_naming_one_job_by_file_identity(tmp_path):
    """first_items: a hard link beside the job, a symbolic link to its folder, another spelling: the same job; a
    hard link in another folder is another job (its relative paths, its output folder, are taken from there)."""
    import os

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    job = tmp_path / "a" / "job.json"
    job.write_text("{}")
    os.link(job, tmp_path / "a" / "copy.json")
    os.link(job, tmp_path / "b" / "job.json")
    os.symlink(tmp_path / "a", tmp_path / "link")
    items = [str(job), str(tmp_path / "a" / "copy.json"), str(tmp_path / "link" / "job.json"),
             os.path.join(str(tmp_path), "a", ".", "job.json"), str(tmp_path / "b" / "job.json"),
             str(tmp_path / "missing.json"), str(tmp_path / "." / "missing.json")]
    assert batch.first_items(items) == [0, 0, 0, 0, 4, 5, 5]
    assert batch.first_items([]) == []


def test_the_summary_keeps_not_run_apart_from_failed():
    from scpainter_blender.core import backend_protocol as p

    results = [{"status": p.ITEM_OK}, {"status": p.ITEM_FAILED}, {"status": p.ITEM_STOPPED},
               {"status": p.ITEM_NOT_RUN}, {"status": p.ITEM_NOT_RUN}]
    s = batch.summary(results)
    assert (s["jobs"], s["ok"], s["failed"], s["stopped"], s["not_run"]) == (5, 1, 1, 1, 2)
    assert s["counts"] == batch.status_counts(results)
    assert set(s) | {"command", "items"} == set(p.BATCH_SUMMARY_FIELDS)
    assert batch.summary([]) == {"jobs": 0, "ok": 0, "failed": 0, "stopped": 0, "not_run": 0, "counts": {}}


def test_a_folder_is_known_by_its_identity_whether_it_exists_or_not(tmp_path):
    """folder_identity: the nearest existing folder by st_dev/st_ino once links are followed, plus the names below
    it that do not exist yet: a symbolic link to the parent, ``..`` through it, and the folder made later agree."""
    import os

    (tmp_path / "a").mkdir()
    os.symlink(tmp_path / "a", tmp_path / "link")
    out, via_link = str(tmp_path / "a" / "out" / "x"), str(tmp_path / "link" / "out" / "x")
    assert batch.folder_identity(out) == batch.folder_identity(via_link)
    assert batch.folder_identity(out) != batch.folder_identity(str(tmp_path / "a" / "out" / "y"))
    before = batch.folder_identity(out)
    os.makedirs(out)
    assert batch.folder_identity(out) == batch.folder_identity(via_link) != before   # now the folder itself
    (tmp_path / "b").mkdir()
    os.symlink(tmp_path / "a" / "out", tmp_path / "b" / "deep")
    # "..", followed where the link leads (as the file system does), not where the spelling suggests
    assert batch.folder_identity(str(tmp_path / "b" / "deep" / ".." / "out" / "x")) == batch.folder_identity(out)


def test_different_jobs_naming_one_output_folder_refuse_the_later_ones(tmp_path):
    """shared_output_items: a copy of a job with a shorter frame range, in the same folder, writing to the same
    output folder (which would delete the first job's other frames), and a job elsewhere reaching it through a
    symbolic link, are refused, naming the job file, ``output_dir``, the other job and what to do; the same job
    listed again (a hard link) is a copy (first_items), not a conflict, and a job that cannot be read is left to
    report its own error."""
    import json
    import os

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    job, short = tmp_path / "a" / "job.json", tmp_path / "a" / "job_short.json"
    job.write_text(json.dumps({"output_dir": "out"}))
    short.write_text(json.dumps({"output_dir": "./out"}))
    os.link(job, tmp_path / "a" / "again.json")
    os.symlink(tmp_path / "a", tmp_path / "b" / "up")
    (tmp_path / "b" / "elsewhere.json").write_text(json.dumps({"output_dir": "up/out"}))
    (tmp_path / "b" / "own.json").write_text(json.dumps({"output_dir": "out"}))
    (tmp_path / "b" / "broken.json").write_text("{not json")
    items = [str(job), str(tmp_path / "a" / "again.json"), str(short), str(tmp_path / "b" / "elsewhere.json"),
             str(tmp_path / "b" / "own.json"), str(tmp_path / "b" / "broken.json"), str(tmp_path / "missing.json")]
    refused = batch.shared_output_items(items)
    assert sorted(refused) == [2, 3]
    for i in (2, 3):
        r = refused[i]
        assert r["file"] == items[i] and r["field"] == "output_dir", r
        assert items[0] in r["error"] and str(tmp_path / "a" / "out") in r["error"], r
        assert "output_dir" in r["hint"] and "own" in r["hint"], r
    assert batch.shared_output_items([]) == {}


def test_a_failed_item_without_a_hint_of_its_own_gets_one():
    """bad_input_fields: an error that carries a hint keeps it; a job path that names a folder or nothing gets one
    saying what the batch needs there."""
    item = "/data/jobs/missing.json"
    fields = batch.bad_input_fields(errors.InputError(item, "(file)", "not found"), item)
    assert fields["file"] == item and fields["hint"] and "job" in fields["hint"], fields
    fields = batch.bad_input_fields(errors.InputError("/data/car.ply", "(file)", "not found"), item)
    assert fields["hint"] and "/data/car.ply" in fields["hint"], fields
    kept = batch.bad_input_fields(errors.InputError(item, "frames", "bad", hint="fix it"), item)
    assert kept["hint"] == "fix it"


def test_ray_addresses_in_the_forms_ray_joins_are_accepted(monkeypatch):
    """Issue 42: auto, local, HOST:PORT (IPv6 in brackets) and ray://HOST:PORT pass; a dashboard URL, another
    scheme or a HOST:PORT without host or with a bad port is refused before any cluster is joined."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    for good in ("auto", "local", "10.0.0.5:6379", "head:6379", "[::1]:6379", "ray://head:10001", " auto "):
        assert batch.ray_address_problem(good) is None, good
        batch.check_ray_address(good)
    for bad, says in (("http://127.0.0.1:8265", "is a web address (the Ray dashboard's"),
                      ("https://ray.example.com", "is a web address"),
                      ("grpc://head:6379", "grpc:// is not a Ray cluster address"),
                      ("head", "expected auto, local, HOST:PORT, ray://HOST:PORT"),
                      (":6379", "expected"), ("head:0", "expected"), ("head:65536", "expected"),
                      ("ray://head", "expected"), ("head/x:1", "expected")):
        with pytest.raises(errors.ArgumentError) as e:
            batch.check_ray_address(bad)
        assert e.value.field == "--ray" and says in e.value.message, (bad, e.value.message)
        assert "ray://HEAD:10001" in e.value.hint and "8265" in e.value.hint


def test_a_dashboard_url_in_the_environment_is_refused_naming_it(monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "http://127.0.0.1:8265")
    for given in ("", None):   # --ray without an address reads RAY_ADDRESS
        with pytest.raises(errors.InputError) as e:
            batch.check_ray_address(given)
        assert (e.value.path, e.value.field) == ("(environment)", "RAY_ADDRESS") and "web address" in e.value.message
        assert "unset RAY_ADDRESS" in e.value.hint
    with pytest.raises(errors.InputError):
        batch.ray_options("", None, None)
    batch.check_ray_address("head:6379")      # an address given wins over the environment's
    assert batch.ray_options(None) == (batch.DEFAULT_RETRIES, batch.DEFAULT_CPUS_PER_JOB)   # no --ray: not read


def test_a_nul_byte_in_a_list_is_refused_naming_its_line(tmp_path):
    """Issue 42: a NUL byte in a batch list reached os.stat (ValueError, a traceback)."""
    listed = tmp_path / "list.txt"
    listed.write_bytes(b"# jobs\na/job.json\nx\x00y/job.json\n")
    for read in (batch.read_job_list, batch.read_list):
        with pytest.raises(errors.InputError) as e:
            read(listed)
        assert e.value.path == str(listed) and e.value.field == "line 3" and "NUL" in e.value.message
