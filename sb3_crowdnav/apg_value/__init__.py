from sb3_crowdnav.apg_value.apg_value import APGValue
from sb3_crowdnav.apg_value.policies import (
    ApgPolicy,
    CadrlPolicy,
    LmPolicy,
    LstmRlPolicy,
    SarlPolicy,
    SfPolicy,
    ValueLookaheadPolicy,
)
from sb3_crowdnav.apg_value.propagation import Propagated, PropagationModel

__all__ = [
    "APGValue",
    "ApgPolicy",
    "CadrlPolicy",
    "LmPolicy",
    "LstmRlPolicy",
    "Propagated",
    "PropagationModel",
    "SarlPolicy",
    "SfPolicy",
    "ValueLookaheadPolicy",
]
