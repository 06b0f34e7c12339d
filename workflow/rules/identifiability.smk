"""The identifiability ladder (dpsi.identifiability): identification runs on three rungs of the twin that
share datapoints and differ in how the targets come about: R0 same model, R1 reconstructed at the
identification resolution, R2 the main pipeline's finer twin. `snakemake identifiability` builds the ladder of
the config; `tables` and `figures` include the rungs and losses listed in `in_tables` (R0 in the quick default).
"""


include: "ladder_runs.smk"


if "identifiability" in ANALYSES:

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
            code=library(
                "identifiability", "twin", "prepare", "reconstruction", "capture"
            ),
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
                ladder_runs(*LADDER_TABLES[w.ladder]), "summary.json"
            ),
            logs=lambda w: run_files(ladder_runs(*LADDER_TABLES[w.ladder]), "log.csv"),
            references=lambda w: ladder_references(
                ladder_runs(*LADDER_TABLES[w.ladder])
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
            labels=lambda w: list(ladder_runs(*LADDER_TABLES[w.ladder]).values()),
            references=lambda w: {
                LADDER_REFERENCE.format(**labels): labels
                for labels in ladder_runs(*LADDER_TABLES[w.ladder]).values()
            },
        script:
            "../scripts/identifiability.py"

    rule identifiability_bias:
        input:
            datapoints=prepared(bias_datapoints()),
            reconstructed=ladder_prepared("R1", bias_datapoints()),
            twin=[f"{RAW}/{i}" for i in bias_datapoints()],
            truth=truth_file(),
            code=library("identifiability", "identification", "simulation", "losses"),
        output:
            sources=multiext(
                "results/tables/identifiability_bias", ".csv", ".md", ".tex"
            ),
            minima=multiext(
                "results/tables/identifiability_minima", ".csv", ".md", ".tex"
            ),
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
