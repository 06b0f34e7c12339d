"""The cluster path's files: the profiles, the resources every job asks for, and the helpers of
scripts/slurm-check.sh (which runs the workflow on a real single-node SLURM cluster; .ci/run calls it)."""

import importlib.util
import json
import os
import re
import subprocess
import sys

import pandas as pd
import pytest
import yaml
from snakemake.settings.types import MaxJobsPerTimespan

from conftest import ROOT, TINY, snakemake


def load_script(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


slurm_check = load_script("slurm_check")
cpu_share = load_script("cpu_share")


def parsed_profile(name, **env):
    """The profile profiles/<name> as Snakemake parses it (YTE included), and DPSI_TAICHI_CACHE after
    parsing, in a fresh process whose environment is this one's with ``env`` (None: unset)."""
    environment = {k: v for k, v in {**os.environ, **env}.items() if v is not None}
    code = ("import json, os; from snakemake.profiles import ProfileConfigFileParser as P; "
            f"p = dict(P().parse(open({str(ROOT / 'profiles' / name / 'config.yaml')!r}))); "
            "print(json.dumps([p, os.environ.get('DPSI_TAICHI_CACHE')]))")
    run = subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def test_slurm_profile_takes_partition_and_account_from_sbatch_variables_and_shares_the_kernel_cache():
    profile, cache = parsed_profile("slurm", SBATCH_PARTITION="gpu-long", SBATCH_ACCOUNT="lab7",
                                    DPSI_TAICHI_CACHE=None, USER="ada")
    assert profile["executor"] == "slurm"
    assert profile["default-resources"] == ["slurm_partition=gpu-long", "slurm_account=lab7"]
    assert cache.startswith("/tmp/dpsi-taichi-cache-")  # node-local, one per user
    profile, cache = parsed_profile("slurm", SBATCH_PARTITION=None, SBATCH_ACCOUNT=None,
                                    DPSI_TAICHI_CACHE="/scratch/kernels")
    assert profile["default-resources"] == []  # the cluster's default partition, the plugin's account
    assert cache == "/scratch/kernels"


def test_workflow_profile_selects_the_greedy_scheduler_and_leaves_resources_to_rules_and_cluster_profiles():
    """Snakemake loads profiles/default beside --profile profiles/slurm, each of its top-level keys
    replacing the other's: default-resources there would drop the cluster's partition and account. Its rate
    limit's timespan is how often Snakemake re-runs job selection while it waits: not every second."""
    profile = yaml.safe_load((ROOT / "profiles" / "default" / "config.yaml").read_text())
    assert profile["scheduler"] == "greedy"
    assert MaxJobsPerTimespan.parse_choice(profile["max-jobs-per-timespan"]).timespan >= 60
    assert "default-resources" not in profile and "set-resources" not in profile
    slurm = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    assert not set(profile) & set(slurm)


def dry_run_jobs(tmp_path, config, **env):
    """rule name -> set of resources lines of the jobs (those with outputs) of a dry run of `all
    identifiability`."""
    environment = {**os.environ, **env}
    run = subprocess.run([sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile"),
                          "--directory", str(tmp_path), "--configfile", str(config), "-n", "all",
                          "identifiability"], capture_output=True, text=True, env=environment)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "workflow specific profile" in run.stdout + run.stderr  # profiles/default is picked up
    jobs = {}
    for block in re.split(r"\n\s*\n", run.stdout):
        rule = re.search(r"^(local)?rule (\w+):", block, re.M)
        if rule and not rule[1] and re.search(r"^\s+output: ", block, re.M):
            resources = re.search(r"^\s+resources: (.*)$", block, re.M)
            jobs.setdefault(rule[2], set()).add(resources[1] if resources else "")
    return jobs


def test_every_job_asks_for_memory_and_time_and_for_a_gpu_only_on_cuda(tmp_path):
    jobs = dry_run_jobs(tmp_path, TINY)
    assert {"identify", "fuse", "cost_measure", "make_tables"} <= set(jobs)
    for rule, resources in jobs.items():
        for line in resources:
            assert re.search(r"\bmem_mb=\d+", line) and re.search(r"\bruntime=\d+", line), (rule, line)
            assert "gres=" not in line, (rule, line)
    config = yaml.safe_load(TINY.read_text())
    config["taichi_arch"] = "cuda"
    cuda = tmp_path / "cuda.yaml"
    cuda.write_text(yaml.safe_dump(config))
    jobs = dry_run_jobs(tmp_path, cuda, DPSI_GPU_GRES="gpu:a100")
    asking = {rule for rule, resources in jobs.items() if all("gres=gpu:a100:1" in r for r in resources)}
    assert {"identify", "baseline", "ood_identified", "cost_measure", "landscape"} <= asking
    assert not {"fuse", "mesh", "twin_datapoint", "make_tables"} & asking  # no simulation, no GPU


def test_cpu_share_tells_the_own_process_from_its_children():
    burn = "import time\nwhile time.process_time() < {}: pass\n"
    parent = (f"import subprocess, sys, time\nsubprocess.run([sys.executable, '-c', {burn.format(1.0)!r}])\n"
              f"{burn.format(0.6)}time.sleep(0.5)\n")
    figures = cpu_share.measure([sys.executable, "-c", parent])
    assert figures["returncode"] == 0
    assert figures["own_cpu_s"] == pytest.approx(0.6, abs=0.15)
    assert figures["children_cpu_s"] == pytest.approx(1.0, abs=0.15)
    assert figures["total_cpu_s"] == pytest.approx(figures["own_cpu_s"] + figures["children_cpu_s"])


SACCT = """\
7|3f2a|rule_identify_wildcards_2_prt_cd_1-round_0|COMPLETED|0:0|00:01:05|01:02.500||1|3000M|12:00:00
7.batch|batch||COMPLETED|0:0|00:01:05|00:00.100|10736K|1||
7.0|python3.11||COMPLETED|0:0|00:01:04|01:02.400|1.5G|1||
8|3f2a|rule_make_tables|FAILED|1:0|1-00:00:02|2:03:04||1|1000M|00:05:00
8.batch|batch||FAILED|1:0|1-00:00:02|00:00.200|20M|1||
"""


def test_job_table_reads_each_job_with_its_rule_its_steps_cpu_and_peak_memory():
    jobs = slurm_check.job_table(SACCT.splitlines()).set_index("job_id")
    assert list(jobs.index) == ["7", "8"]
    assert jobs.loc["7", "rule"] == "identify" and jobs.loc["8", "rule"] == "make_tables"
    assert jobs.loc["7", "elapsed_s"] == 65 and jobs.loc["8", "elapsed_s"] == 86402
    assert jobs.loc["7", "cpu_s"] == pytest.approx(62.5) and jobs.loc["8", "cpu_s"] == 7384
    assert jobs.loc["7", "max_rss_mib"] == 1536 and jobs.loc["8", "max_rss_mib"] == 20
    assert list(jobs.state) == ["COMPLETED", "FAILED"]


def write_tables(folder, **tables):
    for name, frame in tables.items():
        path = folder / "results" / "tables" / f"{name}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        frame.to_csv(path, index=False)


def test_compare_accepts_tables_equal_to_the_tests_tolerance_and_cost_timings_only(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    cost = pd.DataFrame({"motion": ["poking-1"], "particles": [516], "forward_s": [1.35], "taichi_cache": ["warm"]})
    write_tables(a, best=pd.DataFrame({"E": [2.0e5, 3.0]}), cost=cost)
    write_tables(b, best=pd.DataFrame({"E": [2.0e5 * (1 + 1e-8), 3.0]}),
                 cost=cost.assign(forward_s=[2.71], taichi_cache=["cold"]))
    assert slurm_check.main(["compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "results/tables/best.csv: equal to a relative 1e-06" in out
    assert "results/tables/cost.csv: equal but for measured columns" in out


@pytest.mark.parametrize("change", [
    {"best": pd.DataFrame({"E": [2.0e5 * (1 + 1e-5), 3.0]})},
    {"cost": pd.DataFrame({"motion": ["poking-1"], "particles": [517], "forward_s": [1.35],
                           "taichi_cache": ["warm"]})},
])
def test_compare_refuses_a_difference_beyond_the_tolerance_or_in_a_result_column(tmp_path, capsys, change):
    a, b = tmp_path / "a", tmp_path / "b"
    tables = dict(best=pd.DataFrame({"E": [2.0e5, 3.0]}),
                  cost=pd.DataFrame({"motion": ["poking-1"], "particles": [516], "forward_s": [1.35],
                                     "taichi_cache": ["warm"]}))
    write_tables(a, **tables)
    write_tables(b, **{**tables, **change})
    assert slurm_check.main(["compare", str(a), str(b)]) == 1
    assert "DIFFERENT" in capsys.readouterr().out


def test_bad_config_passes_the_schema_and_refuses_every_datapoint(tmp_path):
    bad = tmp_path / "bad.yaml"
    assert slurm_check.main(["bad-config", str(TINY), str(bad)]) == 0
    assert yaml.safe_load(bad.read_text())["simulator"]["max_particles"] == 100
    run = snakemake(tmp_path, "-n", "tables", config=bad)  # the schema accepts it: jobs fail, not start-up
    assert run.returncode == 0, run.stderr[-2000:]


paper_scale = load_script("paper_scale")

DRY_RUN = """\
rule identify:
    input: results/p/twin/prepared/clay-poking-1-round-train-0.npz, results/p/twin/prepared/clay-poking-2-rectangle-train-1.npz, results/p/twin/prepared/clay-poking-2-round-validation-0.npz, src/dpsi/x.py
    output: results/p/twin/runs/L1/prt_cd/6-mix/seed0/summary.json
    resources: tmpdir=/tmp, runtime=720, mem_mb=3000

rule fuse:
    input: results/p/twin/raw/clay-poking-1-round-train-0
    output: results/p/twin/fused/clay-poking-1-round-train-0_after.npy

localrule all:
    input: results/p/twin/tables/motions.csv
"""


def test_paper_scale_models_an_identification_run_from_its_datapoints_and_the_passes():
    jobs = paper_scale.dry_run_jobs(DRY_RUN)
    assert [j["rule"] for j in jobs] == ["identify", "fuse"]
    assert paper_scale.motion_of("clay-poking-shifting-2-round-train-0") == "poking-shifting-2"
    cost = pd.DataFrame({"motion": ["poking-1", "poking-shifting-1", "flattening"], "density": [4e7] * 3,
                         "forward_s": [1.0, 2.0, 5.0], "backward_s": [2.0, 4.0, 10.0]})
    passes = paper_scale.pass_seconds(cost)
    poking_2 = 94 / 87  # steps of poking-2 against poking-1's
    assert passes["poking-2"] == pytest.approx((poking_2, 2 * poking_2))
    tiny = {"identify": 50.0, "fuse": 13.0}
    # 100 iterations × (forward + backward of both training datapoints + forward of the validation one)
    expected = 50 + 100 * (3.0 + 3 * poking_2 + poking_2)
    assert paper_scale.job_cpu_seconds(jobs[0], passes, tiny, cost) == pytest.approx(expected)
    assert paper_scale.job_cpu_seconds(jobs[1], passes, tiny, cost) == pytest.approx(13.0 * 4)
    assert paper_scale.makespan([5, 4, 3, 3, 1], 2) == 8  # 5+3 and 4+3+1
