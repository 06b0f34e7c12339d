"""DPSI: differentiable physics-based system identification of elastoplastic objects.

snakemake -j1 tables                       # the quick default (config/config.yaml)
snakemake -j1 --configfile config/paper.yaml tables
snakemake --profile profiles/slurm --configfile config/paper.yaml all
"""

from snakemake.utils import min_version

min_version("9.0")


# A config given with --configfile is the whole configuration: the quick default is read only when none
# is given, so that its synthetic twin (or any other section) never slips into a user's configuration.
if not workflow.overwrite_configfiles:

    configfile: f"{workflow.basedir}/config/config.yaml"


include: "workflow/rules/common.smk"


if TWIN:

    include: "workflow/rules/twin.smk"


if RELEASE:

    include: "workflow/rules/release.smk"


include: "workflow/rules/reconstruction.smk"
include: "workflow/rules/identification.smk"
include: "workflow/rules/evaluation.smk"
include: "workflow/rules/landscapes.smk"
include: "workflow/rules/cost.smk"
include: "workflow/rules/materials.smk"
include: "workflow/rules/minima.smk"
include: "workflow/rules/heightmap_losses.smk"
include: "workflow/rules/planning.smk"
include: "workflow/rules/convergence.smk"
include: "workflow/rules/identifiability.smk"
include: "workflow/rules/reporting.smk"
