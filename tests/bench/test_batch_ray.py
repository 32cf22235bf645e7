"""``bench/batch_ray.py --smoke`` keeps running: two short render jobs by static sharding (torchrun, one rank) and by
Ray (``batch --ray`` joining the tests' local cluster: no ``ray start``, no ``ray stop``), its table printed and its
JSON written with both arms' wall, busy and idle seconds."""

from bench_support import finite, run_smoke


def test_batch_ray_smoke(tmp_path, ray_cluster, capsys):
    got = run_smoke("batch_ray", tmp_path, "--ray-address", ray_cluster)
    assert "| arm | wall s |" in capsys.readouterr().out
    assert [r["arm"] for r in got["rows"]] == ["static", "ray"] and got["settings"]["smoke"]
    for r in got["rows"]:
        assert r["jobs"] == 2 and finite(r["wall_s"], *r["busy_s"].values(), *r["idle_s"].values())
        assert r["wall_s"] > 0 and sum(r["busy_s"].values()) > 0
