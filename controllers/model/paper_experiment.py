"""The paper's experiment in numbers (standard library only): its calibrated plate and its force limit.

The one home of these numbers in the product code: the controller's `paper_safe_set`
(controllers.model.safe_set, ψ(n) = PAPER_PLATE_STIFFNESS · n, F_max = PAPER_F_MAX) and the vocabulary's
declared defaults (vocabulary.settings: plate_stiffness, assumed_plate_stiffness, f_max), which
every configuration surface takes, read them from here. Standard library only, so that the
vocabulary, which imports it, stays so (tests/test_vocabulary.py).
"""

PAPER_PLATE_STIFFNESS = 11.16  # N/m, the plate's spring as the paper calibrated it (masses at its tip)
PAPER_F_MAX = 0.16  # N, the paper's force limit per facet
