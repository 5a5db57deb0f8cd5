# The learned models (SPEC §4): trainings per model and training seed, each checked; a
# model's draws are its trainings that work.


rule train:
    """One training of a model: its k-th has seed training.seed + k (SPEC §4). Whether it
    works is its health check's; which trainings become draws, the draw rule's."""
    input:
        data=paths.dataset(TRACKS.train_track),
    output:
        weights=f"{paths.TRAINING}/{paths.WEIGHTS}",
        meta=f"{paths.TRAINING}/{paths.META}",
        losses=f"{paths.TRAINING}/{paths.LOSSES}",
    params:
        spec=lambda wildcards: JOBS.write_training(wildcards.model, int(wildcards.training_seed)),
        out=lambda wildcards, output: os.path.dirname(output.weights),
    threads: TRAININGS.threads
    priority: lambda wildcards: TRAININGS.training_priority(wildcards.model)
    resources:
        runtime=240,
        # how often the training writes its resumable checkpoint: a resource, not a param,
        # since it changes no result and so must not retrain a finished model
        checkpoint_every=lambda wildcards: str(TRAININGS.checkpoint_every),
    conda:
        CAPE_ENV
    log:
        paths.log("train", "{model}", "seed{training_seed}.log"),
    benchmark:
        paths.benchmark("train", "{model}", "seed{training_seed}.tsv")
    shell:
        "cape train --model {wildcards.model} --seed {wildcards.training_seed}"
        " --data {input.data:q} --out {params.out:q}"
        " --threads {threads} --checkpoint-every {resources.checkpoint_every}"
        " --spec {params.spec:q} > {log:q} 2>&1"


checkpoint training_health:
    """Did a training work? The checks on the training alone (SPEC §4.2's bar, the stalled
    loss): a checkpoint, since which trainings a model needs depends on them."""
    input:
        weights=f"{paths.TRAINING}/{paths.WEIGHTS}",
        meta=f"{paths.TRAINING}/{paths.META}",
        losses=f"{paths.TRAINING}/{paths.LOSSES}",
        data=paths.dataset(TRACKS.train_track),
    output:
        f"{paths.TRAINING}/{paths.HEALTH}",
    params:
        spec=lambda wildcards: JOBS.write_health("training_health", wildcards.model),
        folder=lambda wildcards, input: os.path.dirname(input.weights),
    conda:
        CAPE_ENV
    log:
        paths.log("health", "{model}", "seed{training_seed}.log"),
    shell:
        "cape check-training --model {wildcards.model}={params.folder:q} --data {input.data:q}"
        " --out {output:q} --spec {params.spec:q} > {log:q} 2>&1"


rule draw:
    """Draw r of a model: its (r + 1)-th training that works, in seed order, up to
    training.max_trainings (SPEC §4); the draw's folder is what every later rule reads. It
    reads every consulted training (its record is checked against its files and the bar)."""
    input:
        unpack(TRAININGS.draw_inputs),
    output:
        weights=f"{paths.MODEL}/{paths.WEIGHTS}",
        meta=f"{paths.MODEL}/{paths.META}",
        losses=f"{paths.MODEL}/{paths.LOSSES}",
    localrule: True
    params:
        # (no `health` while a checkpoint is pending: the job is planned again once it is done)
        trainings=lambda wildcards, input: " ".join(
            f"--training {shlex.quote(os.path.dirname(h))}" for h in getattr(input, "health", [])
        ),
        out=lambda wildcards, output: os.path.dirname(output.weights),
        cap=TRAININGS.draw_max_trainings,
        # the bar each consulted record's verdict is checked against (a changed bar re-decides
        # the draws), and the records' content (a record changed in place does)
        spec=lambda wildcards: JOBS.write_health("draw", wildcards.model),
        records=lambda wildcards, input: TRAININGS.draw_records(getattr(input, "health", [])),
    conda:
        CAPE_ENV
    log:
        paths.log("draw", paths.REP, "{model}.log"),
    shell:
        "cape draw --model {wildcards.model} --replicate {wildcards.replicate} {params.trainings}"
        " --max-trainings {params.cap} --out {params.out:q} --spec {params.spec:q} > {log:q} 2>&1"


rule freeze:
    input:
        weights=f"{paths.MODEL}/{paths.WEIGHTS}",
        meta=f"{paths.MODEL}/{paths.META}",
        data=paths.dataset(TRACKS.train_track),
    output:
        f"{paths.MODEL}/{paths.FROZEN_PHI}",
    params:
        spec=lambda wildcards: JOBS.write_sections("freeze", "data"),
        folder=lambda wildcards, input: os.path.dirname(input.weights),
    conda:
        CAPE_ENV
    log:
        paths.log("freeze", paths.REP, "{model}.log"),
    shell:
        "cape freeze --model {wildcards.model}={params.folder:q} --data {input.data:q} --out {output:q}"
        " --spec {params.spec:q} > {log:q} 2>&1"


rule export_network:
    input:
        weights=f"{paths.MODEL}/{paths.WEIGHTS}",
        meta=f"{paths.MODEL}/{paths.META}",
    output:
        f"{paths.MODEL}/{paths.NETWORK}",
    localrule: True
    params:
        folder=lambda wildcards, input: os.path.dirname(input.weights),
        spec=lambda wildcards: JOBS.write_export(),
    conda:
        CAPE_ENV
    log:
        paths.log("export", paths.REP, "{model}.log"),
    shell:
        "cape export-network --model {wildcards.model}={params.folder:q} --out {output:q}"
        " --spec {params.spec:q} > {log:q} 2>&1"


rule openloop_table:
    input:
        models=lambda wildcards: TRAININGS.trained_models(int(wildcards.replicate)),
        train=paths.dataset(TRACKS.train_track),
        test=paths.dataset(TRACKS.test_track),
    output:
        csv=f"{paths.REPLICATE_TABLES}/table04_openloop_rmse.csv",
        md=f"{paths.REPLICATE_TABLES}/table04_openloop_rmse.md",
        tex=f"{paths.REPLICATE_TABLES}/table04_openloop_rmse.tex",
    params:
        models=lambda wildcards: TRAININGS.model_args(int(wildcards.replicate)),
        spec=lambda wildcards: JOBS.write_sections("openloop_table", "data", "training"),
    conda:
        CAPE_ENV
    log:
        paths.log("tables", paths.REP, "table04_openloop_rmse.log"),
    benchmark:
        paths.benchmark("tables", paths.REP, "table04_openloop_rmse.tsv")
    shell:
        "cape openloop {params.models} --train-data {input.train:q} --test-data {input.test:q}"
        " --out {output.csv:q} --out {output.md:q} --out {output.tex:q} --spec {params.spec:q} > {log:q} 2>&1"


rule complexity_table:
    input:
        models=lambda wildcards: TRAININGS.trained_models(int(wildcards.replicate)),
        test=paths.dataset(TRACKS.test_track),
    output:
        csv=f"{paths.REPLICATE_TABLES}/table01_model_complexity.csv",
        md=f"{paths.REPLICATE_TABLES}/table01_model_complexity.md",
        tex=f"{paths.REPLICATE_TABLES}/table01_model_complexity.tex",
    params:
        models=lambda wildcards: TRAININGS.model_args(int(wildcards.replicate)),
        spec=lambda wildcards: JOBS.write_sections("complexity_table", "training"),
    conda:
        CAPE_ENV
    log:
        paths.log("tables", paths.REP, "table01_model_complexity.log"),
    benchmark:
        paths.benchmark("tables", paths.REP, "table01_model_complexity.tsv")
    shell:
        "cape complexity {params.models} --data {input.test:q}"
        " --out {output.csv:q} --out {output.md:q} --out {output.tex:q} --spec {params.spec:q} > {log:q} 2>&1"


rule figure_models:
    input:
        models=TRAININGS.trained_models(),
        test=paths.dataset(TRACKS.test_track),
    output:
        phi_pdf=paths.figures("model_phi_ethzmobil.pdf"),
        phi_png=paths.figures("model_phi_ethzmobil.png"),
        curves_pdf=paths.figures("training_curves.pdf"),
        curves_png=paths.figures("training_curves.png"),
    params:
        models=TRAININGS.model_args(),
        spec=lambda wildcards: JOBS.write_sections("figure_models", "data", "models"),
    conda:
        CAPE_ENV
    log:
        paths.log("figures", "models.log"),
    shell:
        "cape plot-models {params.models} --data {input.test:q}"
        " --phi-out {output.phi_pdf:q} --phi-out {output.phi_png:q}"
        " --curves-out {output.curves_pdf:q} --curves-out {output.curves_png:q}"
        " --spec {params.spec:q} > {log:q} 2>&1"
