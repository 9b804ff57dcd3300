"""Standard-library helpers shared by ``hardware`` and ``calibration``.

Those two layers must not import each other (each installs and tests on its own), yet both write
files a crash must never leave half-written. A helper they share cannot live in either, nor in
``sim2real`` (which imports both and pulls the simulator), so it lives here: a leaf package with
no dependencies beyond the standard library, installed by every profile.
"""
