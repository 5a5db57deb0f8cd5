"""The ground-truth question in stages (SPEC §10, revision 6): its plan, what a look
decides, its record between runs, the driver that runs the stages, its report and its
published answer."""
