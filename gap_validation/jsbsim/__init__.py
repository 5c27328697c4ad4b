"""JSBSim front end: the nonlinear 6-DOF flight model of FlightGear and ArduPilot SITL as a third simulator.

- :mod:`gap_validation.jsbsim.linearize`: an aircraft shipped with the ``jsbsim`` wheel trimmed straight and
  level (:func:`~gap_validation.jsbsim.linearize.trim`) and linearised by JSBSim's own ``FGLinearization``
  (:func:`~gap_validation.jsbsim.linearize.linearize`), written as a validation config
  (``gap-validate linearize --jsbsim``).
- :mod:`gap_validation.jsbsim.flight`: the test card of :mod:`gap_validation.core.testcard` flown in the
  nonlinear model (``gap-validate simulate --jsbsim``), a
  :class:`~gap_validation.core.simulation.SimulatedFlight`.

``jsbsim`` is imported inside the functions that need it, never when this package is imported: the CLI and the
core stay free of it until a JSBSim command runs.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "trim": "linearize", "Linearization": "linearize", "available_aircraft": "linearize",
    "write_config": "linearize", "simulate_jsbsim_flight": "flight", "JSBSimFlight": "flight",
    "Turbulence": "flight"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
