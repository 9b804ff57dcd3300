"""System identification: fit the servo model to logged trajectories, closing the real-to-sim
loop (``sim2real sysid``). ``record`` excites an arm, ``fit`` recovers the model, ``apply``
writes an updated ArmSpec and a DR preset centred on the fit."""
