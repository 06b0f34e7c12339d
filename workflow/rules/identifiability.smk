"""The identifiability ladder (dpsi.identifiability): identification runs on three rungs of the twin that
share datapoints and differ in how the targets come about: R0 same model, R1 reconstructed at the
identification resolution, R2 the main pipeline's finer twin. At R0 the PCD and PRT targets are the same
particles, so a PCD loss's run there is its PRT loss's run, relabelled (ladder_same_target). `snakemake
identifiability` builds the ladder of the config; `tables` and `figures` include the rungs and losses listed
in `in_tables` (R0 in the quick default). Beside the runs: where the bias comes from and where each loss has
its minimum (identifiability_bias), and the losses over (E, σ_y) around the truth on every rung
(ladder_landscape, identifiability_landscapes).
"""


include: "ladder_runs.smk"


if "identifiability" in ANALYSES:

    rule ladder_same_model:
        input:
            datapoint=f"{RESULTS}/prepared/{{id}}.npz",
            truth=truth_file(),
            code=code("ladder_same_model"),
        output:
            f"{LADDER_ROOT}/R0/prepared/{{id}}.npz",
        log:
            log_file("identifiability/R0_{id}"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=2000,
            runtime=10,
            gres=GPU_GRES,
        params:
            material=lambda w: TABLE.set_index("id").loc[w.id, "material"],
            simulator=simulator_params(),
        script:
            "../scripts/ladder_same_model.py"

    rule ladder_reconstructed_twin:
        input:
            truth=truth_file(),
            code=code("ladder_reconstructed_twin"),
        output:
            prepared=f"{LADDER_ROOT}/{{rung}}/prepared/{{id}}.npz",
            raw=directory(f"{LADDER_ROOT}/{{rung}}/raw/{{id}}"),
        log:
            log_file("identifiability/{rung}_{id}"),
        wildcard_constraints:
            rung="R1|R1m",
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
            motion_error=lambda w: (
                LADDER.get("motion_error", {}) if w.rung == "R1m" else {}
            ),
        script:
            "../scripts/ladder_reconstructed_twin.py"

    use rule register as register_ladder with:
        input:
            datapoint=f"{LADDER_ROOT}/R1m/prepared/{{id}}.npz",
            code=code("register"),
        output:
            datapoint=f"{LADDER_ROOT}/R1r/prepared/{{id}}.npz",
            record=f"{LADDER_ROOT}/R1r/prepared/{{id}}.json",
        log:
            log_file("identifiability/R1r_{id}"),

    use rule identify as identify_ladder with:
        input:
            training=lambda w: ladder_prepared(
                w.rung, ladder_training_ids(w.level, w.dataset)
            ),
            validation=lambda w: ladder_prepared(
                w.rung, ladder_validation_ids(w.level, w.dataset)
            ),
            truth=truth_file(),
            code=code("identify"),
        output:
            summary=f"{LADDER_RUN}/summary.json",
            log=f"{LADDER_RUN}/log.csv",
        log:
            log_file("identifiability/{rung}_L{level}_{loss}_{dataset}_seed{seed}"),
        wildcard_constraints:
            rung="|".join(RUNGS),
        resources:
            mem_mb=3000,
            runtime=lambda w: run_minutes(
                ladder_training_ids(w.level, w.dataset)
                + ladder_validation_ids(w.level, w.dataset),
                run_iterations(w.rung, w.dataset),
            ),
            gres=GPU_GRES,
        params:
            iterations=lambda w: run_iterations(w.rung, w.dataset),
            initial=LADDER["initial"],
            known=LADDER.get("known", {}),
            select=lambda w: run_selection(w.dataset),
            uncertainty=LADDER.get("uncertainty", True),
            simulator=simulator_params(),

    rule ladder_same_target:
        input:
            summary=lambda w: f"{same_target_run(w)}/summary.json",
            log=lambda w: f"{same_target_run(w)}/log.csv",
            code=code("ladder_same_target"),
        output:
            summary=f"{LADDER_SAME_TARGET}/summary.json",
            log=f"{LADDER_SAME_TARGET}/log.csv",
        log:
            log_file("identifiability/R0_L{level}_pcd_{metric}_{dataset}_seed{seed}"),
        wildcard_constraints:
            metric="cd|emd",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=500,
            runtime=5,
        params:
            loss=lambda w: f"pcd_{w.metric}",
        script:
            "../scripts/ladder_same_target.py"

    ruleorder: ladder_same_target > identify_ladder

    rule ladder_reference:
        input:
            training=lambda w: ladder_prepared(
                w.rung, ladder_training_ids(w.level, w.dataset)
            ),
            validation=lambda w: ladder_prepared(
                w.rung, ladder_validation_ids(w.level, w.dataset)
            ),
            truth=truth_file(),
            code=code("ladder_reference"),
        output:
            LADDER_REFERENCE,
        log:
            log_file("identifiability/{rung}_L{level}_{dataset}_reference"),
        wildcard_constraints:
            rung="|".join(RUNGS),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=2000,
            runtime=20,
            gres=GPU_GRES,
        params:
            simulator=simulator_params(),
        script:
            "../scripts/ladder_reference.py"

    rule identifiability_results:
        input:
            summaries=lambda w: run_files(LADDER_TABLES[w.ladder], "summary.json"),
            logs=lambda w: run_files(LADDER_TABLES[w.ladder], "log.csv"),
            references=lambda w: ladder_references(LADDER_TABLES[w.ladder]),
            code=code("identifiability"),
        output:
            table=table_files("{ladder}", "../report/identifiability.rst"),
            figure=figure_files("{ladder}", "../report/identifiability_figure.rst"),
            uncertainty=(
                table_files(
                    "{ladder}_uncertainty", "../report/identifiability_uncertainty.rst"
                )
                + table_files("{ladder}_coverage", "../report/coverage.rst")
                + figure_files(
                    "{ladder}_uncertainty", "../report/uncertainty_figure.rst"
                )
                if LADDER_UNCERTAINTY
                else []
            ),
        log:
            log_file("{ladder}"),
        wildcard_constraints:
            ladder="|".join(LADDER_TABLES),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        params:
            references=lambda w: {
                LADDER_REFERENCE.format(**labels): labels
                for labels in LADDER_TABLES[w.ladder].values()
            },
        script:
            "../scripts/identifiability.py"

    rule identifiability_bias:
        input:
            datapoints=prepared(bias_datapoints()),
            reconstructed=ladder_prepared("R1", bias_datapoints()),
            twin=[f"{RAW}/{i}" for i in bias_datapoints()],
            after_clouds=[f"{RESULTS}/fused/{i}_after.npy" for i in bias_datapoints()],
            truth=truth_file(),
            code=code("identifiability_bias"),
        output:
            sources=table_files("identifiability_bias"),
            minima=table_files("identifiability_minima"),
        log:
            log_file("identifiability_bias"),
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

    rule ladder_landscape:
        input:
            training=lambda w: ladder_prepared(
                w.rung, ladder_training_ids(1, w.dataset)
            ),
            truth=truth_file(),
            code=code("ladder_landscape"),
        output:
            LADDER_LANDSCAPE,
        log:
            log_file("identifiability/{rung}_{dataset}_landscape"),
        wildcard_constraints:
            rung="|".join(RUNGS),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=3000,
            # minutes: 36 simulations per datapoint, 1-5 s each on a CPU (flattening the longest)
            runtime=lambda w: 10 + 4 * len(ladder_training_ids(1, w.dataset)),
            gres=GPU_GRES,
        params:
            losses=LADDER["losses"],
            simulator=simulator_params(),
        script:
            "../scripts/ladder_landscape.py"

    rule identifiability_landscapes:
        input:
            landscapes=[
                LADDER_LANDSCAPE.format(rung=rung, dataset=dataset)
                for rung, dataset in LANDSCAPE_LABELS
            ],
            code=code("ladder_landscapes"),
        output:
            table=table_files(
                "identifiability_landscape", "../report/identifiability_landscape.rst"
            ),
            figure=figure_files(
                "identifiability_landscape",
                "../report/identifiability_landscape_figure.rst",
            ),
        log:
            log_file("identifiability_landscape"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        params:
            labels=LANDSCAPE_LABELS,
        script:
            "../scripts/ladder_landscapes.py"

    rule identifiability:
        input:
            ladder_outputs("identifiability"),
            rules.identifiability_bias.output,
            rules.identifiability_landscapes.output,
        localrule: True
