"""The synthetic twin: raw captures simulated from known parameters (only when the config has `twin`)."""


def twin_settings():
    twin = config["twin"]
    return {"seed": twin["seed"], "density": twin["density"], "dx": twin["dx"],
            "max_particles": twin.get("max_particles", 22000), "groups": twin["groups"]}


rule twin_table:
    output:
        table=f"{RAW}/datapoints.csv",
        layout=f"{RAW}/dataset.yaml",
        truth=f"{RAW}/truth.json",
    input:
        library("twin", "rawdata", "datasets", "parameters"),
    params:
        twin=twin_settings(),
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    log:
        f"logs/{config['dataset']}/twin_table.log",
    script:
        "../scripts/twin_table.py"


rule twin_datapoint:
    output:
        directory(f"{RAW}/{{id}}"),
    input:
        rules.twin_table.output,
        library("twin", "shapes", "capture", "motions", "effectors", "simulation"),
    params:
        twin=twin_settings(),
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    log:
        f"logs/{config['dataset']}/twin/{{id}}.log",
    script:
        "../scripts/twin_datapoint.py"
