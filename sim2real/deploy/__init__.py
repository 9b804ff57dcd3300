"""Run one policy on any ``hardware.Arm``: MuJoCo (SimArm), the emulator over a pty, a real arm."""
