"""Real-to-sim reconstruction (SPEC §3), one rule per stage. `check_raw` validates a raw datapoint once;
the stages read its record instead of validating the raw files again."""


rule check_raw:
    input:
        raw_datapoint,
        code("check_raw"),
    output:
        f"{RESULTS}/checked/{{id}}.json",
    log:
        log_file("check_raw/{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    script:
        "../scripts/check_raw.py"


rule fuse:
    input:
        checked=f"{RESULTS}/checked/{{id}}.json",
        code=code("fuse"),
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
        checked=f"{RESULTS}/checked/{{id}}.json",
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
        checked=f"{RESULTS}/checked/{{id}}.json",
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
    script:
        "../scripts/targets.py"


rule trajectory:
    input:
        checked=f"{RESULTS}/checked/{{id}}.json",
        code=code("trajectory"),
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
    script:
        "../scripts/trajectory.py"


rule prepare:
    input:
        particles=f"{RESULTS}/particles/{{id}}.npy",
        targets=f"{RESULTS}/targets/{{id}}.npz",
        trajectory=f"{RESULTS}/trajectories/{{id}}.npz",
        checked=f"{RESULTS}/checked/{{id}}.json",
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
    script:
        "../scripts/prepare.py"


rule register:
    input:
        datapoint=f"{RESULTS}/prepared/{{id}}.npz",
        code=code("register"),
    output:
        datapoint=f"{RESULTS}/registered/{{id}}.npz",
        record=f"{RESULTS}/registered/{{id}}.json",
    log:
        log_file("register/{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
        gres=GPU_GRES,
    params:
        level=lambda w: level_of(w.id),
        simulator=simulator_params(),
    script:
        "../scripts/register.py"
