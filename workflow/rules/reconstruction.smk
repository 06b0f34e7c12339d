"""Real-to-sim reconstruction (SPEC §3), one rule per stage."""


rule fuse:
    input:
        raw_datapoint,
        library("prepare", "reconstruction", "rawdata", "pointclouds"),
    output:
        f"{RESULTS}/fused/{{id}}_{{state}}.npy",
    log:
        f"logs/{config['dataset']}/fuse/{{id}}_{{state}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/fuse.py"


rule mesh:
    input:
        raw_datapoint,
        points=f"{RESULTS}/fused/{{id}}_{{state}}.npy",
        code=library("prepare", "reconstruction", "rawdata"),
    output:
        f"{RESULTS}/meshes/{{id}}_{{state}}.obj",
    log:
        f"logs/{config['dataset']}/mesh/{{id}}_{{state}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/mesh.py"


rule fill:
    input:
        mesh=f"{RESULTS}/meshes/{{id}}_before.obj",
        code=library("prepare", "reconstruction"),
    output:
        f"{RESULTS}/particles/{{id}}.npy",
    log:
        f"logs/{config['dataset']}/fill/{{id}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        density=config["reconstruction"]["density"],
    script:
        "../scripts/fill.py"


rule targets:
    input:
        mesh=f"{RESULTS}/meshes/{{id}}_after.obj",
        points=f"{RESULTS}/fused/{{id}}_after.npy",
        particles=f"{RESULTS}/particles/{{id}}.npy",
        layout=f"{RAW}/datapoints.csv",
        code=library("prepare", "reconstruction", "heightmap"),
    output:
        f"{RESULTS}/targets/{{id}}.npz",
    log:
        f"logs/{config['dataset']}/targets/{{id}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        density=config["reconstruction"]["density"],
    script:
        "../scripts/targets.py"


rule trajectory:
    input:
        raw_datapoint,
        library("prepare", "motions", "rawdata"),
    output:
        f"{RESULTS}/trajectories/{{id}}.npz",
    log:
        f"logs/{config['dataset']}/trajectory/{{id}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=2,
    script:
        "../scripts/trajectory.py"


rule prepare:
    input:
        particles=f"{RESULTS}/particles/{{id}}.npy",
        targets=f"{RESULTS}/targets/{{id}}.npz",
        trajectory=f"{RESULTS}/trajectories/{{id}}.npz",
        code=library("datapoint"),
    output:
        f"{RESULTS}/prepared/{{id}}.npz",
    log:
        f"logs/{config['dataset']}/prepare/{{id}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=2,
    params:
        density=config["reconstruction"]["density"],
        row=lambda wildcards: TABLE.set_index("id").loc[wildcards.id].to_dict(),
    script:
        "../scripts/prepare.py"
