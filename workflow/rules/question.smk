# The ground-truth question in stages (SPEC §10, revision 6; docs/question.md). `cape question`
# writes each stage's plan (results/question/stage.yaml: the draws per model and the seeds per
# draw) and runs this target with it merged over the config; the target is the stage's runs,
# and with them the trainings, draws and solvers they read. Without a plan it is empty.


def question_targets():
    """Every file of the runs the current stage's plan names, with their compiled solvers."""
    plan = (config.get("question") or {}).get("plan")
    if not plan:
        return []
    settings = QuestionSettings.from_config(config, SOURCE)
    runs = [GRID.get(run, run) for run in stage_runs(settings, Plan.from_config(plan))]
    return [*solver_outputs(runs), *run_outputs(runs)]


rule question:
    """The runs of the question's current stage (`cape question` runs it, stage by stage)."""
    input:
        question_targets(),
    localrule: True
