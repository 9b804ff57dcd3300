"""Learning on the arm: a Gymnasium env over the hardware layer (``arm_env``), keys for a human
beside it (``keys``), and ``sim2real finetune`` (``runner``: the control loop with a numpy
``actor``; ``learner``: the SB3 model in its own process; ``checkpoint``: source and run dir; ``defaults``: the learner settings measured to work)."""
