"""The published real clay data imported as the raw dataset (only when the config's `release` names it)."""


rule import_release:
    input:
        meshes=[
            str(p) for _, pair in released_pairs() for p in (pair.before, pair.after)
        ],
        code=code("import_release"),
    output:
        table=f"{RAW}/datapoints.csv",
        record=f"{RAW}/import.json",
        folders=[directory(f"{RAW}/{i}") for i in IDS],
    log:
        log_file("import_release"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        source=config["release"]["source"],
        release=config["release"],
    script:
        "../scripts/import_release.py"
