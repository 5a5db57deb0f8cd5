# The ground-truth question in stages (SPEC §10, revision 6; docs/question.md). `cape question`
# writes each stage's plan (results/question/stage.yaml: the draws per model and the seeds per
# draw) and runs this target with it merged over the config; the target is the stage's runs,
# and with them the trainings, draws and solvers they read. Without a plan it is empty.


rule question:
    """The runs of the question's current stage (`cape question` runs it, stage by stage)."""
    input:
        QUESTION.targets(),
    localrule: True


rule notebook_question:
    """Figure 15 and table 10: the question's rows through its looks, from the looks.csv that
    `cape question` writes after each stage (it runs this rule when it stops)."""
    input:
        notebook=f"{NOTEBOOK_DIR}/question.ipynb",
        looks=paths.QUESTION_LOOKS,
    output:
        NOTEBOOKS.figures("question", paths.scoped(paths.QUESTION, "figures"), ".pdf"),
        NOTEBOOKS.figures("question", paths.scoped(paths.QUESTION, "figures"), ".png"),
        NOTEBOOKS.tables("question", paths.scoped(paths.QUESTION, "tables")),
        notebook=paths.scoped(paths.QUESTION, "notebooks", "question.ipynb"),
        html=paths.scoped(paths.QUESTION, "notebooks", "question.html"),
    params:
        nb=lambda wildcards, input: JOBS.write_parameters(
            "notebook_question",
            looks_path=input.looks,
            figure_dir=paths.scoped(paths.QUESTION, "figures"),
            table_dir=paths.scoped(paths.QUESTION, "tables"),
        ),
    conda:
        CAPE_ENV
    log:
        paths.scoped(paths.QUESTION, "logs", "notebook_question.log"),
    localrule: True
    shell:
        run_notebook("-f {params.nb:q}")
