"""The paper's values (docs/model.md §4): the inertias at capture (J0) and docked (J2)
[kg m^2], the times the deployment and the docking begin [s], and its phases' names."""

PAPER_J0 = ((625.0, 5.5, 3.0), (5.5, 350.0, 4.0), (3.0, 4.0, 1000.0))
PAPER_J2 = ((3945.4, 66.7, 12.8), (66.7, 3663.5, 160.0), (12.8, 160.0, 2011.8))
PAPER_DEPLOY_TIME = 500.0  # s
PAPER_DOCK_TIME = 2600.0  # s
PHASE_NAMES = ("capture", "deployment", "detumble")  # the phases these times begin and end
