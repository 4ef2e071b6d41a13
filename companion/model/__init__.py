"""Dynamics model of the hexacopter + 2-DOF arm (paper section II); see ``dynamics``."""

from companion.model.dynamics import ManipulatorModel, ModelParameters, ModelTerms

__all__ = ["ManipulatorModel", "ModelParameters", "ModelTerms"]
