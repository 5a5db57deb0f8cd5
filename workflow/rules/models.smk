# The learned models (SPEC §4): one training job per model and training replicate.


rule train:
    input:
        data=dataset_path(config["data"]["train_track"]),
    output:
        weights="results/models/rep{replicate}/{model}/model.pt",
        meta="results/models/rep{replicate}/{model}/meta.json",
        losses="results/models/rep{replicate}/{model}/loss.csv",
    params:
        cfg=lambda wildcards: model_config_json(wildcards.model, int(wildcards.replicate)),
        out=lambda wildcards, output: os.path.dirname(output.weights),
    threads: config["training"]["threads"]
    # the longest training first (EPM's 3000 epochs are the study's critical path), and every
    # training before any rollout
    priority: lambda wildcards: 100 + int(config["models"][wildcards.model]["train"]["epochs"]) // 10
    resources:
        runtime=240,
        # how often the training writes its resumable checkpoint: a resource, not a param,
        # since it changes no result and so must not retrain a finished model
        checkpoint_every=lambda wildcards: str(config["training"].get("checkpoint_every", 60)),
    conda:
        CAPE_ENV
    log:
        "results/logs/train/rep{replicate}/{model}.log",
    benchmark:
        "results/benchmarks/train/rep{replicate}/{model}.tsv"
    shell:
        "cape train --model {wildcards.model} --replicate {wildcards.replicate}"
        " --data {input.data:q} --out {params.out:q}"
        " --threads {threads} --checkpoint-every {resources.checkpoint_every}"
        " --config-json {params.cfg:q} > {log:q} 2>&1"


rule freeze:
    input:
        weights="results/models/rep{replicate}/{model}/model.pt",
        meta="results/models/rep{replicate}/{model}/meta.json",
        data=dataset_path(config["data"]["train_track"]),
    output:
        "results/models/rep{replicate}/{model}/frozen_phi.json",
    params:
        cfg=lambda wildcards: config_json("data"),
        folder=lambda wildcards, input: os.path.dirname(input.weights),
    conda:
        CAPE_ENV
    log:
        "results/logs/freeze/rep{replicate}/{model}.log",
    shell:
        "cape freeze --model {wildcards.model}={params.folder:q} --data {input.data:q} --out {output:q}"
        " --config-json {params.cfg:q} > {log:q} 2>&1"


rule export_network:
    input:
        weights="results/models/rep{replicate}/{model}/model.pt",
        meta="results/models/rep{replicate}/{model}/meta.json",
    output:
        "results/models/rep{replicate}/{model}/network.npz",
    localrule: True
    params:
        folder=lambda wildcards, input: os.path.dirname(input.weights),
        cfg=lambda wildcards: export_config_json(),
    conda:
        CAPE_ENV
    log:
        "results/logs/export/rep{replicate}/{model}.log",
    shell:
        "cape export-network --model {wildcards.model}={params.folder:q} --out {output:q}"
        " --config-json {params.cfg:q} > {log:q} 2>&1"


rule openloop_table:
    input:
        models=lambda wildcards: trained_models(int(wildcards.replicate)),
        train=dataset_path(config["data"]["train_track"]),
        test=dataset_path(config["data"]["test_track"]),
    output:
        csv="results/tables/rep{replicate}/table04_openloop_rmse.csv",
        md="results/tables/rep{replicate}/table04_openloop_rmse.md",
        tex="results/tables/rep{replicate}/table04_openloop_rmse.tex",
    params:
        models=lambda wildcards: model_args(int(wildcards.replicate)),
        cfg=lambda wildcards: config_json("data", "training"),
    conda:
        CAPE_ENV
    log:
        "results/logs/tables/rep{replicate}/table04_openloop_rmse.log",
    benchmark:
        "results/benchmarks/tables/rep{replicate}/table04_openloop_rmse.tsv"
    shell:
        "cape openloop {params.models} --train-data {input.train:q} --test-data {input.test:q}"
        " --out {output.csv:q} --out {output.md:q} --out {output.tex:q} --config-json {params.cfg:q} > {log:q} 2>&1"


rule complexity_table:
    input:
        models=lambda wildcards: trained_models(int(wildcards.replicate)),
        test=dataset_path(config["data"]["test_track"]),
    output:
        csv="results/tables/rep{replicate}/table01_model_complexity.csv",
        md="results/tables/rep{replicate}/table01_model_complexity.md",
        tex="results/tables/rep{replicate}/table01_model_complexity.tex",
    params:
        models=lambda wildcards: model_args(int(wildcards.replicate)),
        cfg=lambda wildcards: config_json("training"),
    conda:
        CAPE_ENV
    log:
        "results/logs/tables/rep{replicate}/table01_model_complexity.log",
    benchmark:
        "results/benchmarks/tables/rep{replicate}/table01_model_complexity.tsv"
    shell:
        "cape complexity {params.models} --data {input.test:q}"
        " --out {output.csv:q} --out {output.md:q} --out {output.tex:q} --config-json {params.cfg:q} > {log:q} 2>&1"


rule figure_models:
    input:
        models=trained_models(),
        test=dataset_path(config["data"]["test_track"]),
    output:
        phi_pdf="results/figures/model_phi_ethzmobil.pdf",
        phi_png="results/figures/model_phi_ethzmobil.png",
        curves_pdf="results/figures/training_curves.pdf",
        curves_png="results/figures/training_curves.png",
    params:
        models=model_args(),
        cfg=lambda wildcards: config_json("data", "models"),
    conda:
        CAPE_ENV
    log:
        "results/logs/figures/models.log",
    shell:
        "cape plot-models {params.models} --data {input.test:q}"
        " --phi-out {output.phi_pdf:q} --phi-out {output.phi_png:q}"
        " --curves-out {output.curves_pdf:q} --curves-out {output.curves_png:q}"
        " --config-json {params.cfg:q} > {log:q} 2>&1"
