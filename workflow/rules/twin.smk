"""The synthetic twin: raw captures simulated from known parameters (only when the config has `twin`)."""


rule twin_table:
    input:
        code("twin_table"),
    output:
        table=f"{RAW}/datapoints.csv",
        layout=f"{RAW}/dataset.yaml",
        truth=f"{RAW}/truth.json",
    log:
        log_file("twin_table"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        twin=twin_settings(),
    script:
        "../scripts/twin_table.py"


rule twin_datapoint:
    input:
        rules.twin_table.output,
        code("twin_datapoint"),
    output:
        directory(f"{RAW}/{{id}}"),
    log:
        log_file("twin/{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        twin=twin_settings(),
    script:
        "../scripts/twin_datapoint.py"
