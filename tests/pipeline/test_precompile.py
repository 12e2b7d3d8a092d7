"""The set-up's kernel compilation (``python -m rjfit.pipeline.precompile``, run by setup.sh) runs
each region model's short fit, the measured default's and an effects fit, and leaves nothing behind. About 10 s once the cache exists."""
import tempfile
from pathlib import Path

from rjfit.pipeline.precompile import precompile


def test_precompile_fits_each_region_model_and_leaves_no_folder():
    before = set(Path(tempfile.gettempdir()).glob("rjfit-precompile-*"))
    said = []
    seconds = precompile(say=said.append)
    assert len(said) == 6 and all(line.startswith("compiled the ") for line in said)
    assert seconds > 0
    assert set(Path(tempfile.gettempdir()).glob("rjfit-precompile-*")) == before
