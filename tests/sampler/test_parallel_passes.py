"""The parallel passes with effects' lobe terms give the serial passes' sums, on their first call after compiling.

Numba 0.68 mis-compiled a ``parallel=True`` kernel called from inside another jitted
function when effects' lobe terms were passed: on a fresh cache the first call of
``b_sums_newton`` over more than :data:`~rjfit.sampler.passes.sums.PARALLEL_MIN_OBS`
observations returned zeros, and a cached form crashed a 128 x 128 fit with ``--effects
ambient`` ("expected array(float64, 2d, C), got None" in ``per_pixel_two_cases``). The
outer functions now dispatch to the parallel kernels from Python. The check runs in a fresh
process with its own empty Numba cache (the failure was on a first compile), about 15 s.
"""
import json
import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import json
    import numpy as np
    from rjfit.sampler.passes import cells, sums
    from rjfit.sampler.regions.materials.passes import labels as label_passes
    from rjfit.sampler.passes.lobe import LobeTerms

    rng = np.random.default_rng(0)
    height = width = 128
    n_lights = 6                              # 98,304 observations: three times PARALLEL_MIN_OBS
    pixel = np.repeat(np.arange(height * width), n_lights)      # sorted by pixel, as the problems are
    n = pixel.size
    row, col = (pixel // width).astype(np.int16), (pixel % width).astype(np.int16)
    y = rng.uniform(0.0, 2.0, n).astype(np.float32)
    C = rng.uniform(0.1, 1.0, n).astype(np.float32)
    log_cos_hn = np.log(rng.uniform(0.3, 1.0, n)).astype(np.float32)
    n_gammas, n_columns = 12, 6
    ext = LobeTerms(cb=C.copy(), mask_w=0.0, tan_v=np.zeros(0, np.float32), tan_l=np.zeros(0, np.float32),
                    amb=rng.uniform(0.0, 0.1, n).astype(np.float32),
                    amb_j=rng.integers(0, n_columns - 1, n).astype(np.int32),
                    amb_fy=rng.uniform(0.0, 1.0, n).astype(np.float32),
                    table=rng.uniform(0.5, 1.0, (n_gammas, n_columns)), grid=np.array([-2.0, 9.0, 1.0]))
    chunks = [(a, a + n // 4) for a in range(0, n, n // 4)]      # whole pixels, each below PARALLEL_MIN_OBS
    assert all(b - a < sums.PARALLEL_MIN_OBS for a, b in chunks) and n >= sums.PARALLEL_MIN_OBS

    whole_sums = sums.b_sums_newton(y, C, log_cos_hn, np.array([0]), np.array([n]), 12.0, ext)
    chunk_sums = sum(sums.b_sums_newton(y, C, log_cos_hn, np.array([a]), np.array([b]), 12.0, ext)
                     for a, b in chunks)

    x_old = rng.uniform(20.0, 100.0, height)              # one u vector: two regions, step 1
    labels = (x_old[row] < col + 0.5).astype(np.int32)
    theta = np.array([[100.0, 0.8, 12.0, 0.1], [70.0, 0.6, 30.0, 0.1]])
    whole_cases = [np.zeros(height * width), np.zeros(height * width)]
    cells.per_pixel_two_cases(y, C, log_cos_hn, row, col, labels, x_old, 1, theta, width, whole_cases[0],
                              whole_cases[1], ext)
    chunk_cases = [np.zeros(height * width), np.zeros(height * width)]
    for a, b in chunks:
        cells.per_pixel_two_cases(y[a:b], C[a:b], log_cos_hn[a:b], row[a:b], col[a:b], labels[a:b], x_old, 1,
                                  theta, width, chunk_cases[0], chunk_cases[1], ext.take(np.arange(a, b)))

    n_pix = height * width
    whole_pixels = label_passes.pixel_log_lik(y, C, log_cos_hn, pixel, theta, n_pix, ext)
    chunk_pixels = sum(label_passes.pixel_log_lik(y[a:b], C[a:b], log_cos_hn[a:b], pixel[a:b], theta, n_pix,
                                                  ext.take(np.arange(a, b))) for a, b in chunks)

    def rel(first, second):
        first, second = np.asarray(first), np.asarray(second)
        return float(np.max(np.abs(first - second)) / np.max(np.abs(second)))

    print(json.dumps({"sums_rel": rel(whole_sums, chunk_sums), "sums_zero": bool(np.all(whole_sums == 0)),
                      "cases_rel": max(rel(w, c) for w, c in zip(whole_cases, chunk_cases)),
                      "pixels_rel": rel(whole_pixels, chunk_pixels)}))
""")


def test_parallel_passes_with_lobe_terms_match_the_serial_sums_on_a_fresh_compile(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    done = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert not result["sums_zero"], "the parallel sums came back zero"
    # the same float64 sums of the same float32 terms in another grouping: rounding only (~1e-13 relative)
    assert result["sums_rel"] < 1e-9, result
    assert result["cases_rel"] < 1e-9, result
    assert result["pixels_rel"] < 1e-9, result
