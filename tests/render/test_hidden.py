"""render_hidden's ``spp`` reaches the path tracer (real Mitsuba, 8 x 8 images, a few seconds)."""
import json

import numpy as np

from rjfit.data.exr import read_exr
from rjfit.render.hidden import INTERREFLECTION_SPP, render_hidden


def _images(folder):
    meta = json.loads((folder / "dataset.json").read_text())
    return meta, np.stack([read_exr(folder / name)["R"] for name in meta["images"]])


def test_interreflection_spp_reaches_the_render(tmp_path):
    default_meta, default = _images(render_hidden("interreflection", tmp_path / "default", resolution=8,
                                                  noise_variance=0.0))
    meta, images = _images(render_hidden("interreflection", tmp_path / "spp4", resolution=8, noise_variance=0.0,
                                         spp=4))
    assert default_meta["spp"] == INTERREFLECTION_SPP == 16      # None keeps the kind's old default
    assert meta["spp"] == 4
    # Same seed, same direct light; only the indirect paths' Monte Carlo average differs with spp.
    assert not np.array_equal(images, default)
