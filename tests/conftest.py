"""Settings for the whole suite."""

import os

# The engine computes a scene's sigma ladders in the background once its field is in use
# (engine.runtime.ladder_jobs): minutes of CPU beside every engine a test starts, on a CI
# that must stay within 45 minutes. tests/engine/test_ladder.py turns it on where it tests it.
os.environ.setdefault("SKELASM_LIVE_SIGMA", "0")
