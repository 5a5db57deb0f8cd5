# Shared: the config validated (cape.workflow.start) and the study's workflow built once
# (cape.workflow.targets). The rules read its stages by name: TRACKS (cape.workflow.tracks),
# TRAININGS (trainings and draws), RUNS (rollouts and solvers), NOTEBOOKS (tables and
# notebooks), QUESTION (question_runs); W holds the targets that span them; each job's file
# (its --spec) comes from JOBS (cape.workflow.job_files).

import os
import shlex
import sys

from snakemake.io import report as in_report  # `report(` opening a line is Snakemake's directive

from cape.layout import paths
from cape.workflow.job_files import JobFiles
from cape.workflow.notebooks import DECLARED, TABLE_EXTS, run_notebook
from cape.workflow.runs import RUN_FOLDER, RUN_LOG, RUN_STEM
from cape.workflow.start import Refusing, prepare, refusals
from cape.workflow.targets import StudyWorkflow

with refusals():  # a bad config value: its one-line reason, no traceback
    prepare(config, workflow.is_main_process)
    W = StudyWorkflow.from_config(
        config,
        # a target lists every file of a job: Snakemake rebuilds a deleted file only if asked for
        outputs=lambda rule, **wildcards: [str(p).format(**wildcards) for p in getattr(rules, rule).output],
        health=lambda model, seed: checkpoints.training_health.get(model=model, training_seed=seed).output[0],
    )
    JOBS = Refusing(JobFiles(config))  # a job file refused: its one line, not frames
TRACKS, TRAININGS, RUNS, NOTEBOOKS, QUESTION = W.tracks, W.trainings, W.runs, W.notebooks, W.question
SCOPES = NOTEBOOKS.scopes
CAPE_ENV = "../envs/cape.yaml"  # every rule's software environment for `--sdm conda`
NOTEBOOK_DIR = os.path.join(workflow.basedir, "notebooks")  # beside the Snakefile, whatever -d is


wildcard_constraints:
    **W.constraints(),


def reported_figures(notebook, folder, caption, category):
    """The PNG copies of a notebook's figures for the report, each labelled with its number and
    title (cape.study.reports.outputs), so that a category lists its figures in order."""
    return [
        in_report(f"{folder}/{name}.png", caption=caption, category=category,
                  labels={"figure": name[:5], "title": title})
        for name, title in DECLARED[notebook].figures.items()
    ]  # fmt: skip
