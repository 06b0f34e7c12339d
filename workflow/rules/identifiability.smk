"""The identifiability ladder (dpsi.identifiability): identification runs on three rungs of the twin that
share datapoints and differ in how the targets come about: R0 same model, R1 reconstructed at the
identification resolution, R2 the main pipeline's finer twin. `snakemake identifiability` builds the ladder of
the config; `tables` and `figures` include the rungs listed in `tables_rungs` (R0 in the quick default)."""

import itertools

if "identifiability" in ANALYSES:
    if "twin" not in config:
        raise WorkflowError(
            "analyses.identifiability needs a synthetic twin (the truth): add a `twin` section to the config"
        )
    LADDER = ANALYSES["identifiability"]
    LADDER_ROOT = f"{RESULTS}/identifiability"
    LADDER_RUN = f"{LADDER_ROOT}/{{rung}}/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}"
    LADDER_REFERENCE = f"{LADDER_ROOT}/{{rung}}/L{{level}}/{{dataset}}/reference.json"

    def ladder_prepared(rung, ids):
        """Prepared datapoints of a rung: R2 is the main pipeline's."""
        if rung == "R2":
            return prepared(ids)
        return [f"{LADDER_ROOT}/{rung}/prepared/{i}.npz" for i in ids]

    def ladder_runs(rungs):
        """Folder → labels of every ladder run on `rungs`."""
        runs = {}
        for rung, level, loss, dataset, seed in itertools.product(
            rungs, LADDER["levels"], LADDER["losses"], LADDER["datasets"], LADDER["seeds"]
        ):
            try:
                training_ids(level, dataset), validation_ids(level)
            except ValueError as err:
                raise WorkflowError(f"analysis identifiability: {err}")
            labels = dict(rung=rung, level=level, loss=loss, dataset=dataset, seed=seed)
            runs[LADDER_RUN.format(**labels)] = labels
        return runs

    def ladder_references(runs):
        return sorted(
            {LADDER_REFERENCE.format(**labels) for labels in runs.values()}
        )

    LADDER_TABLES = {"identifiability": LADDER["rungs"]}
    TABLES_RUNGS = LADDER.get("tables_rungs", LADDER["rungs"])
    if list(TABLES_RUNGS) != list(LADDER["rungs"]):
        LADDER_TABLES["identifiability_" + "-".join(TABLES_RUNGS)] = TABLES_RUNGS

    def ladder_outputs(name):
        return [f"results/tables/{name}.{s}" for s in ("csv", "md", "tex")] + [
            f"results/figures/{name}.{s}" for s in ("png", "pdf")
        ]

    TABLES_LADDER = list(LADDER_TABLES)[-1]
    ANALYSIS_TABLES += ladder_outputs(TABLES_LADDER)[:3]
    ANALYSIS_FIGURES += ladder_outputs(TABLES_LADDER)[3:]

    rule ladder_same_model:
        input:
            datapoint=f"{RESULTS}/prepared/{{id}}.npz",
            truth=truth_file(),
            code=library("identifiability", "identification", "simulation", "datapoint"),
        output:
            f"{LADDER_ROOT}/R0/prepared/{{id}}.npz",
        log:
            f"logs/{config['dataset']}/identifiability/R0_{{id}}.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=2000,
            runtime=10,
            gpu=1 if config.get("taichi_arch") == "cuda" else 0,
        params:
            material=lambda w: TABLE.set_index("id").loc[w.id, "material"],
            simulator=simulator_params(),
        script:
            "../scripts/ladder_same_model.py"

    rule ladder_reconstructed_twin:
        input:
            truth=truth_file(),
            code=library("identifiability", "twin", "prepare", "reconstruction", "capture"),
        output:
            prepared=f"{LADDER_ROOT}/R1/prepared/{{id}}.npz",
            raw=directory(f"{LADDER_ROOT}/R1/raw/{{id}}"),
        log:
            f"logs/{config['dataset']}/identifiability/R1_{{id}}.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=4000,
            runtime=30,
        params:
            twin=twin_settings(),
            simulator=simulator_params(),
            density=config["reconstruction"]["density"],
        script:
            "../scripts/ladder_reconstructed_twin.py"

    use rule identify as identify_ladder with:
        input:
            training=lambda w: ladder_prepared(w.rung, training_ids(w.level, w.dataset)),
            validation=lambda w: ladder_prepared(w.rung, validation_ids(w.level)),
            truth=truth_file(),
            code=IDENTIFY_CODE,
        output:
            summary=f"{LADDER_RUN}/summary.json",
            log=f"{LADDER_RUN}/log.csv",
        log:
            f"logs/{config['dataset']}/identifiability/{{rung}}_L{{level}}_{{loss}}_{{dataset}}_seed{{seed}}.log",
        wildcard_constraints:
            rung="R[0-2]",
        params:
            iterations=LADDER["iterations"],
            initial=LADDER["initial"],
            simulator=simulator_params(),

    rule ladder_reference:
        input:
            training=lambda w: ladder_prepared(w.rung, training_ids(w.level, w.dataset)),
            validation=lambda w: ladder_prepared(w.rung, validation_ids(w.level)),
            truth=truth_file(),
            code=library("identifiability", "identification", "simulation", "losses"),
        output:
            LADDER_REFERENCE,
        log:
            f"logs/{config['dataset']}/identifiability/{{rung}}_L{{level}}_{{dataset}}_reference.log",
        wildcard_constraints:
            rung="R[0-2]",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=2000,
            runtime=20,
            gpu=1 if config.get("taichi_arch") == "cuda" else 0,
        params:
            simulator=simulator_params(),
        script:
            "../scripts/ladder_reference.py"

    rule identifiability_results:
        input:
            summaries=lambda w: run_files(
                ladder_runs(LADDER_TABLES[w.ladder]), "summary.json"
            ),
            logs=lambda w: run_files(ladder_runs(LADDER_TABLES[w.ladder]), "log.csv"),
            references=lambda w: ladder_references(
                ladder_runs(LADDER_TABLES[w.ladder])
            ),
            code=library("identifiability", "reporting"),
        output:
            table=report(
                "results/tables/{ladder}.csv",
                caption="../report/identifiability.rst",
                category="Tables",
            ),
            other_tables=multiext("results/tables/{ladder}", ".md", ".tex"),
            png=report(
                "results/figures/{ladder}.png",
                caption="../report/identifiability_figure.rst",
                category="Figures",
            ),
            pdf="results/figures/{ladder}.pdf",
        log:
            "logs/{ladder}.log",
        wildcard_constraints:
            ladder="|".join(LADDER_TABLES),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        params:
            labels=lambda w: list(ladder_runs(LADDER_TABLES[w.ladder]).values()),
            references=lambda w: {
                LADDER_REFERENCE.format(**labels): labels
                for labels in ladder_runs(LADDER_TABLES[w.ladder]).values()
            },
        script:
            "../scripts/identifiability.py"

    def bias_datapoints():
        """The level-1 training datapoints of the ladder's datasets (the sources of bias are per datapoint)."""
        ids = [i for d in LADDER["datasets"] for i in training_ids(min(LADDER["levels"]), d)]
        return list(dict.fromkeys(ids))

    rule identifiability_bias:
        input:
            datapoints=prepared(bias_datapoints()),
            reconstructed=ladder_prepared("R1", bias_datapoints()),
            twin=[f"{RAW}/{i}" for i in bias_datapoints()],
            truth=truth_file(),
            code=library("identifiability", "identification", "simulation", "losses"),
        output:
            sources=multiext("results/tables/identifiability_bias", ".csv", ".md", ".tex"),
            minima=multiext("results/tables/identifiability_minima", ".csv", ".md", ".tex"),
        log:
            "logs/identifiability_bias.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=3000,
            runtime=30,
        params:
            simulator=simulator_params(),
            density=config["reconstruction"]["density"],
        script:
            "../scripts/identifiability_bias.py"

    rule identifiability:
        input:
            ladder_outputs("identifiability"),
            rules.identifiability_bias.output,
        localrule: True
