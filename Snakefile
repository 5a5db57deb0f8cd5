# CAPE: control algorithm performance evaluation under learned vehicle dynamics models.
#
#   snakemake --cores 2            the whole study
#   snakemake --cores 2 TARGET     one output and only what it needs
#
# Rules live in workflow/rules/, split by stage; helpers in workflow/rules/common.smk.

from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/tracks.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/models.smk"
include: "workflow/rules/reference.smk"
include: "workflow/rules/rollouts.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/study.smk"
include: "workflow/rules/question.smk"


rule all:
    input:
        W.all_targets(),
    default_target: True
