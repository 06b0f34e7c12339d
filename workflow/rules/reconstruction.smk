"""Real-to-sim reconstruction (SPEC §3), one rule per stage."""


def raw_datapoint(wildcards):
    return [f"{RAW}/{wildcards.id}", f"{RAW}/datapoints.csv"]


rule fuse:
    output:
        f"{RESULTS}/fused/{{id}}_{{state}}.npy",
    input:
        raw_datapoint,
        library("prepare", "reconstruction", "rawdata", "pointclouds"),
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    log:
        f"logs/{config['dataset']}/fuse/{{id}}_{{state}}.log",
    script:
        "../scripts/fuse.py"


rule mesh:
    output:
        f"{RESULTS}/meshes/{{id}}_{{state}}.obj",
    input:
        raw_datapoint,
        points=f"{RESULTS}/fused/{{id}}_{{state}}.npy",
        code=library("prepare", "reconstruction", "rawdata"),
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    log:
        f"logs/{config['dataset']}/mesh/{{id}}_{{state}}.log",
    script:
        "../scripts/mesh.py"


rule fill:
    output:
        f"{RESULTS}/particles/{{id}}.npy",
    input:
        mesh=f"{RESULTS}/meshes/{{id}}_before.obj",
        code=library("prepare", "reconstruction"),
    params:
        density=config["reconstruction"]["density"],
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    log:
        f"logs/{config['dataset']}/fill/{{id}}.log",
    script:
        "../scripts/fill.py"


rule targets:
    output:
        f"{RESULTS}/targets/{{id}}.npz",
    input:
        mesh=f"{RESULTS}/meshes/{{id}}_after.obj",
        points=f"{RESULTS}/fused/{{id}}_after.npy",
        particles=f"{RESULTS}/particles/{{id}}.npy",
        layout=f"{RAW}/datapoints.csv",
        code=library("prepare", "reconstruction", "heightmap"),
    params:
        density=config["reconstruction"]["density"],
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    log:
        f"logs/{config['dataset']}/targets/{{id}}.log",
    script:
        "../scripts/targets.py"


rule trajectory:
    output:
        f"{RESULTS}/trajectories/{{id}}.npz",
    input:
        raw_datapoint,
        library("prepare", "motions", "rawdata"),
    threads: 1
    resources:
        mem_mb=500,
        runtime=2,
    log:
        f"logs/{config['dataset']}/trajectory/{{id}}.log",
    script:
        "../scripts/trajectory.py"


rule prepare:
    output:
        f"{RESULTS}/prepared/{{id}}.npz",
    input:
        particles=f"{RESULTS}/particles/{{id}}.npy",
        targets=f"{RESULTS}/targets/{{id}}.npz",
        trajectory=f"{RESULTS}/trajectories/{{id}}.npz",
        code=library("datapoint"),
    params:
        density=config["reconstruction"]["density"],
        row=lambda wildcards: TABLE.set_index("id").loc[wildcards.id].to_dict(),
    threads: 1
    resources:
        mem_mb=500,
        runtime=2,
    log:
        f"logs/{config['dataset']}/prepare/{{id}}.log",
    script:
        "../scripts/prepare.py"
