"""Real-to-sim reconstruction (SPEC §3), one rule per stage."""


rule fuse:
    input:
        raw_datapoint,
        code("fuse"),
    output:
        f"{RESULTS}/fused/{{id}}_{{state}}.npy",
    log:
        log_file("fuse/{id}_{state}"),
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
        code=code("mesh"),
    output:
        f"{RESULTS}/meshes/{{id}}_{{state}}.obj",
    log:
        log_file("mesh/{id}_{state}"),
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
        code=code("fill"),
    output:
        f"{RESULTS}/particles/{{id}}.npy",
    log:
        log_file("fill/{id}"),
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
        raw=raw_config_files(),
        code=code("targets"),
    output:
        f"{RESULTS}/targets/{{id}}.npz",
    log:
        log_file("targets/{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        density=config["reconstruction"]["density"],
        raw=RAW,
    script:
        "../scripts/targets.py"


rule trajectory:
    input:
        raw_datapoint,
        code("trajectory"),
    output:
        f"{RESULTS}/trajectories/{{id}}.npz",
    log:
        log_file("trajectory/{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=2,
    params:
        raw=RAW,
        row=lambda wildcards: TABLE.set_index("id").loc[wildcards.id].to_dict(),
    script:
        "../scripts/trajectory.py"


rule prepare:
    input:
        particles=f"{RESULTS}/particles/{{id}}.npy",
        targets=f"{RESULTS}/targets/{{id}}.npz",
        trajectory=f"{RESULTS}/trajectories/{{id}}.npz",
        raw=raw_config_files(),
        code=code("prepare"),
    output:
        f"{RESULTS}/prepared/{{id}}.npz",
    log:
        log_file("prepare/{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=2,
    params:
        density=config["reconstruction"]["density"],
        row=lambda wildcards: TABLE.set_index("id").loc[wildcards.id].to_dict(),
        raw=RAW,
    script:
        "../scripts/prepare.py"
