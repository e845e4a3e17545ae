# enclab: logged encoder experiments -> quantization error (propagation.smk, batch.smk:
# enclab.propagation), low-resolution encoder (lrde.smk: enclab.lrde), residual effects
# (residuals.smk: enclab.residuals), rig fit (rig.smk: enclab.rig) and design (design.smk:
# enclab.design). This file is wiring only; each stage is a rule file in
# workflow/rules/ whose script (scripts/<rule>.py) calls the enclab package (workflow/enclab/).

configfile: "config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/propagation.smk"
include: "workflow/rules/batch.smk"
include: "workflow/rules/lrde.smk"
include: "workflow/rules/residuals.smk"
include: "workflow/rules/chunks.smk"
include: "workflow/rules/design.smk"
include: "workflow/rules/rig.smk"


rule all:
    default_target: True
    input:
        all_targets(),
