"""Data sets with one (or two) effects hidden in them, rendered with Mitsuba: what the
criticism (:mod:`rjfit.diagnose`) is tested and validated on.

Where Mitsuba has a built-in for the effect, the data set uses it (not rjfit's extended
closed form), so a test that names the effect cannot pass by construction:

ambient            paper_sphere + a built-in ``constant`` environment emitter (radiance 3 =
                   0.03 x reference intensity), its image path-traced once at 4096 spp and added
                   to every light's image (at 16 spp per image the emitter's Monte Carlo noise,
                   variance ~4, drowned everything else).
camera_response    paper_sphere rendered noise-free, encoded with colour-science's sRGB curve
                   (``colour.cctf_encoding(x, function='sRGB')``) at a white level 1.05 x the
                   brightest value, then read noise (variance 0.1) added to the stored values.
camera_sensor      the same sRGB camera with the read noise (variance 0.1) added to the linear
                   radiance BEFORE the curve, as a sensor adds it (so the stored values' noise
                   sd follows the curve's slope: 12.92 in the toe, small in the highlights);
                   the curve's linear extension below 0 (colour-science's) keeps negative values.
camera_gamma_sensor  a power-law camera W (x / W)^(1/2.2) (``GAMMA_POWER``), the read noise
                   added before it; a sensor clips negative sums at 0, and the data set declares
                   0 dark (those observations leave the fit, as a dark threshold drops them).
light_calibration  paper_sphere with light 3 emitting 20 % more in Mitsuba than the data set's
                   JSON (what the fitter reads) says.
interreflection    dented_plaster (concave), path integrator max_depth 8, 16 spp (``spp``), visibility
                   kept (cast shadows are in the valid mask).
cast_shadows       dented_plaster, direct light only (max_depth 2), its shadow-ray visibility
                   dropped from the data set (so shadowed observations look valid).
fresnel            a sphere with back lights (angles 105-130 degrees from the view, where
                   <h.v> is small) and front lights, its material Mitsuba's built-in
                   ``roughplastic`` (Beckmann, alpha = sqrt(2/(gamma+2)), the Beckmann lobe
                   closest to Blinn-Phong of exponent gamma; a dielectric coating of IOR 1.5,
                   i.e. F0 = 0.04, over a diffuse base). Its lobe is a microfacet lobe (with
                   Smith masking and the coating's transmission on the diffuse part), not
                   exactly Blinn: the test asks the workflow to name the dominant missing effect.
fresnel_plugin     the same scene with ``rjfit_blinn_ext`` (F0 = 0.04): only Fresnel is missing.
ggx_plugin         the back-lit sphere with ``rjfit_blinn_ext`` (ggx_w = 1: a GGX lobe of the regions' roughness).
ggx_plastic        the ``fresnel`` scene with Mitsuba's ``roughplastic`` of distribution "ggx" (the same
                   alpha = sqrt(2/(gamma+2)), IOR 1.5): a GGX dielectric, its lobe GGX with Smith-GGX
                   shadowing under the coating's Fresnel.
rough_plastic      the ``ggx_plastic`` scene with ONE roughness for every material (alpha ``ROUGH_PLASTIC_ALPHA``):
                   Mitsuba's own ``roughplastic``, exactly the library's ``ggx`` + ``rough_coating`` (the
                   regions' fitted gamma giving the lobe's alpha, ``alpha_coat`` the interface's).
coated_plugin      the back-lit sphere with ``rjfit_blinn_ext`` (ggx_w = 1, coat_w = 1, coat_eta = 1.5: a GGX lobe
                   under a dielectric coating, its diffuse part through the smooth interface; the
                   library's ``ggx`` + ``coating``, exactly).
masking            the back-lit sphere with ``rjfit_blinn_ext`` (mask_w = 1, Smith-Beckmann G).
second_lobe        paper_sphere whose materials are Mitsuba's built-in ``blendbsdf``: 70 % rjfit's
                   Blinn-Phong plugin and 30 % a built-in ``roughconductor`` (GGX, alpha 0.15, a
                   perfect conductor, specular reflectance the material's scale): a second lobe
                   of another family; the library's ``second_lobe`` with v = 0.3 / 0.7, alpha2 = 0.15.
anisotropic_lobe   the second_lobe stack with an ANISOTROPIC GGX ``roughconductor`` (alpha_u 0.05, alpha_v
                   0.3 along the mesh's tangent frame): a lobe outside the library, whose lobes are
                   isotropic (a highlight stretched along one tangent direction).
ambient+light_calibration  both at once on paper_sphere.
clean              paper_sphere as is.
"""
from __future__ import annotations

import json
import math
import tempfile
from functools import partial
from pathlib import Path

import numpy as np

from rjfit.data.exr import read_exr
from rjfit.io import write_json_atomic
from rjfit.render.effect_scenes import trace_centre_rays
from rjfit.render.ext_plugin import EXT_PLUGIN_NAME, register_ext
from rjfit.render.mitsuba_scene import activate
from rjfit.render.render import load_scene_definition, render_dataset, scene_from_dataset_meta

__all__ = ["HIDDEN", "render_hidden", "backlit_sphere_definition", "hidden_post_process"]

AMBIENT_RELATIVE = 0.03
CALIBRATED_LIGHT = 3
CALIBRATION_ERROR = 1.2
SRGB_WHITE = 1.05
FRESNEL_F0 = 0.04
COATING_ETA = 1.5
AMBIENT_SPP = 4096
AMBIENT_STREAM = 15        # purpose tag of the ambient image's path-tracing stream (mitsuba_seed)


def backlit_sphere_definition():
    """paper_sphere's sphere and materials with 5 of its front lights and 5 back lights."""
    scene = load_scene_definition("paper_sphere")
    scene["name"] = "backlit_sphere"
    front = scene["lights"][::2]
    back = []
    for alpha, phi in ((105, 20), (112, 95), (120, 170), (125, 250), (130, 320)):
        a, p = math.radians(alpha), math.radians(phi)
        back.append({"kind": "point", "intensity": 100.0,
                     "position": [round(2.2 * math.sin(a) * math.cos(p), 4), round(2.2 * math.sin(a) * math.sin(p), 4),
                                  round(2.2 * math.cos(a), 4)]})
    scene["lights"] = front + back
    return scene


def _roughplastic(materials, reference_intensity, distribution="beckmann", alpha=None):
    def override(index):
        m = materials[index]
        scale = m["I0"] / reference_intensity
        roughness = math.sqrt(2.0 / (m["gamma"] + 2.0)) if alpha is None else alpha
        return {"type": "roughplastic", "distribution": distribution, "alpha": roughness,
                "int_ior": 1.5, "ext_ior": 1.0,
                "diffuse_reflectance": {"type": "rgb", "value": [scale * m["kd"]] * 3},
                "specular_reflectance": {"type": "rgb", "value": [1.0] * 3}}
    return override


SECOND_LOBE_WEIGHT = 0.3
SECOND_LOBE_ALPHA = 0.15


#: ``anisotropic_lobe``'s roughness along the two tangent directions (u: the mesh's dp/du)
ANISOTROPIC_ALPHAS = (0.05, 0.3)


def _second_lobe(materials, reference_intensity, roughness=None):
    """``blendbsdf`` of the Blinn plugin and a GGX ``roughconductor`` of ``roughness`` (its
    ``alpha``, or ``alpha_u`` and ``alpha_v``; None: alpha ``SECOND_LOBE_ALPHA``)."""
    from rjfit.render.mitsuba_scene import material_dict

    roughness = {"alpha": SECOND_LOBE_ALPHA} if roughness is None else roughness

    def override(index):
        m = materials[index]
        scale = m["I0"] / reference_intensity
        return {"type": "blendbsdf", "weight": SECOND_LOBE_WEIGHT, "first": material_dict(m, reference_intensity),
                "second": {"type": "roughconductor", "distribution": "ggx", **roughness,
                           "material": "none", "specular_reflectance": {"type": "rgb", "value": [scale] * 3}}}
    return override


def _ext_plugin(materials, reference_intensity, **params):
    activate()
    register_ext()

    def override(index):
        m = materials[index]
        return {"type": EXT_PLUGIN_NAME, "kd": m["kd"], "gamma": m["gamma"], "scale": m["I0"] / reference_intensity,
                **params}
    return override


def _ambient_image(scene, resolution, radiance, seed, spp=AMBIENT_SPP):
    """What a built-in ``constant`` environment emitter adds to every image: rendered once by
    Mitsuba (the scene with the environment and no other light, pixel-centre rays, ``spp``
    samples in one wavefront) and added to each light's image; light transport is linear,
    so this is the image of the scene with both emitters, with far less Monte Carlo noise
    than rendering the environment again with every light."""
    activate()
    with tempfile.TemporaryDirectory() as scratch:
        geometry = render_dataset(dict(scene, lights=scene["lights"][:1]), Path(scratch) / "g", resolution=resolution,
                                  noise_variance=0.0)
        meta = json.loads((geometry / "dataset.json").read_text())
        env = {"ambient": {"type": "constant", "radiance": {"type": "rgb", "value": [radiance] * 3}}}
        mitsuba_scene = scene_from_dataset_meta(meta, geometry, lights=[], max_depth=8, extra=env)
        image = trace_centre_rays(mitsuba_scene, spp=spp, seed=(seed, AMBIENT_STREAM))
        mask = read_exr(geometry / "geometry.exr")["mask"] > 0.5
    return np.where(mask, image, 0.0)


def _edit_meta(path, edit):
    meta = json.loads((Path(path) / "dataset.json").read_text())
    edit(meta)
    write_json_atomic(Path(path) / "dataset.json", meta)


def hidden_post_process(ambient_image, camera, images, noise_before_curve=False, power=None):
    """The hidden effects applied to rendered radiance (``images`` (L, H, W, C)): ambient light,
    then an sRGB camera with read noise after its curve (or before it), or a power-law camera.

    Parameters
    ----------
    ambient_image : ndarray (H, W) or None
        What the environment adds to every image (:func:`render_hidden`'s ambient kind); None: none.
    camera : (numpy.random.Generator, float) or None
        The read noise's generator and variance, added after the sRGB encoding (white level
        ``SRGB_WHITE`` times the brightest noise-free value); None: a linear camera, no noise added here.
    noise_before_curve : bool
        Add the read noise to the linear radiance and encode the sum (a sensor's order; the
        curve's linear extension below 0 keeps negative sums) instead of adding it to the
        encoded values.
    power : float, optional
        A power-law camera instead of sRGB: ``W (max(x, 0) / W)^(1 / power)`` of the linear
        radiance plus the read noise (always before the curve; a sensor clips its negative sums
        at 0, which the data set declares dark).
    """
    if ambient_image is not None:
        images = images + ambient_image[None, :, :, None]
    if camera is None:
        return images
    import colour

    rng, noise_variance = camera
    white = SRGB_WHITE * float(images.max())
    noise = rng.normal(0.0, math.sqrt(noise_variance), size=images.shape[:3] + (1,))
    if power is not None:
        return white * np.power(np.clip((images + noise) / white, 0.0, None), 1.0 / power)
    if noise_before_curve:
        return white * np.asarray(colour.cctf_encoding((images + noise) / white, function="sRGB"))
    encoded = white * np.asarray(colour.cctf_encoding(np.clip(images / white, 0.0, None), function="sRGB"))
    return encoded + noise


INTERREFLECTION_SPP = 16   # render_hidden's default for interreflection (its tests' data sets)
CAST_SHADOWS_SPP = 1       # direct light only: one sample is exact (the same ray each time)


def _paper_sphere_hidden(kinds, out_dir, options):
    """paper_sphere with ambient light, a miscalibrated light and an sRGB camera (each where ``kinds`` has it)."""
    resolution, seed, noise_variance = options["resolution"], options["seed"], options["noise_variance"]
    scene = load_scene_definition("paper_sphere")
    extra = None
    ambient_image = None
    if "ambient" in kinds:
        ambient_image = _ambient_image(scene, resolution, AMBIENT_RELATIVE * scene["reference_intensity"],
                                       scene.get("seed", 0) if seed is None else seed)
    nominal = json.loads(json.dumps(scene["lights"]))
    if "light_calibration" in kinds:
        scene["lights"][CALIBRATED_LIGHT]["intensity"] *= CALIBRATION_ERROR
    camera = None
    if kinds & CAMERAS:
        rng = np.random.default_rng(np.random.SeedSequence([scene.get("seed", 0) if seed is None else seed, 0xC0]))
        options = dict(options, noise_variance=0.0)
        camera = (rng, noise_variance)
    # ambient light reaches the sensor before its response curve: add it first
    post = None if ambient_image is None and camera is None else partial(
        hidden_post_process, ambient_image, camera, noise_before_curve="camera_sensor" in kinds,
        power=GAMMA_POWER if "camera_gamma_sensor" in kinds else None)
    path = render_dataset(scene, out_dir, extra=extra, post_process=post, **options)
    if "light_calibration" in kinds:
        _edit_meta(path, lambda meta: meta.update(lights=nominal, hidden_calibration={
            "light": CALIBRATED_LIGHT, "true_factor": CALIBRATION_ERROR}))
    if "camera_gamma_sensor" in kinds:
        _edit_meta(path, lambda meta: meta.update(noise_variance=noise_variance, dark=0.0, hidden_response={
            "curve": f"power law W (x / W)^(1/{GAMMA_POWER})", "white_level_factor": SRGB_WHITE,
            "noise": "before the curve (linear), negative sums clipped at 0 (declared dark)",
            "read_noise_variance": noise_variance}))
    elif kinds & CAMERAS:
        before = "camera_sensor" in kinds
        # the stored values' noise: the read noise's, or (before the curve) at most the toe's, 12.92^2 times
        # it (the declared variance sets the floor below which a stored value is refused as bad input)
        _edit_meta(path, lambda meta: meta.update(
            noise_variance=noise_variance * (12.92 ** 2 if before else 1.0), hidden_response={
                "curve": "sRGB (colour.cctf_encoding)", "white_level_factor": SRGB_WHITE,
                "noise": "before encoding (linear)" if before else "after encoding",
                "read_noise_variance": noise_variance}))
    return path


def render_hidden(kind, out_dir, *, resolution=32, seed=None, noise_variance=0.1, spp=None):
    """Render the hidden-effect data set ``kind`` (see the module docstring) into ``out_dir``.

    Parameters
    ----------
    kind : str
        One of ``HIDDEN``, or several joined by ``+`` where a builder exists.
    out_dir : path
        The data set folder.
    resolution, seed, noise_variance
        As :func:`rjfit.render.render.render_dataset`'s.
    spp : int, optional
        Samples per pixel of every light's image (the data set's ``spp``); None: each kind's
        default (``INTERREFLECTION_SPP``, ``CAST_SHADOWS_SPP``, else the scene's), as before this
        argument. Only indirect light is random; the ambient image keeps ``AMBIENT_SPP``.

    Raises
    ------
    ValueError
        For an unknown kind, a combination without a builder, or an spp below 1.
    """
    out_dir = Path(out_dir)
    kinds = set(kind.split("+"))
    unknown = kinds - set(HIDDEN)
    if unknown:
        raise ValueError(f"unknown hidden effect(s) {sorted(unknown)}; known: {HIDDEN}")
    options = dict(resolution=resolution, seed=seed, noise_variance=noise_variance, hidden_effects=sorted(kinds),
                   spp=spp)
    if len(kinds & CAMERAS) > 1:
        raise ValueError(f"one camera per data set, not {sorted(kinds & CAMERAS)}")
    if kinds <= {"ambient", "light_calibration", "clean"} | CAMERAS:
        return _paper_sphere_hidden(kinds, out_dir, options)
    if kinds in ({"second_lobe"}, {"anisotropic_lobe"}):
        scene = load_scene_definition("paper_sphere")
        activate()
        alpha_u, alpha_v = ANISOTROPIC_ALPHAS
        roughness = {"alpha_u": alpha_u, "alpha_v": alpha_v} if kinds == {"anisotropic_lobe"} else None
        return render_dataset(scene, out_dir, bsdf_override=_second_lobe(scene["materials"], scene["reference_intensity"],
                                                                         roughness), **options)
    if kinds == {"interreflection"}:
        options["spp"] = INTERREFLECTION_SPP if spp is None else spp
        return render_dataset("dented_plaster", out_dir, **options)
    if kinds == {"cast_shadows"}:
        scene = load_scene_definition("dented_plaster")
        scene["max_depth"] = 2
        options["spp"] = CAST_SHADOWS_SPP if spp is None else spp
        path = render_dataset(scene, out_dir, **options)
        (Path(path) / "visibility.exr").unlink()
        _edit_meta(path, lambda meta: meta.update(visibility=None))
        return path
    backlit = {"fresnel", "fresnel_plugin", "masking", "ggx_plugin", "ggx_plastic", "coated_plugin", "rough_plastic"}
    if kinds & backlit and len(kinds) == 1:
        scene = backlit_sphere_definition()
        materials, reference = scene["materials"], scene["reference_intensity"]
        if kinds == {"fresnel"}:
            override = _roughplastic(materials, reference)
        elif kinds == {"ggx_plastic"}:
            override = _roughplastic(materials, reference, distribution="ggx")
        elif kinds == {"rough_plastic"}:
            override = _roughplastic(materials, reference, distribution="ggx", alpha=ROUGH_PLASTIC_ALPHA)
        elif kinds == {"fresnel_plugin"}:
            override = _ext_plugin(materials, reference, f0=FRESNEL_F0)
        elif kinds == {"ggx_plugin"}:
            override = _ext_plugin(materials, reference, ggx_w=1.0)
        elif kinds == {"coated_plugin"}:
            override = _ext_plugin(materials, reference, ggx_w=1.0, coat_w=1.0, coat_eta=COATING_ETA)
        else:
            override = _ext_plugin(materials, reference, mask_w=1.0)
        return render_dataset(scene, out_dir, bsdf_override=override, **options)
    raise ValueError(f"no builder for the combination {sorted(kinds)}")


#: the sRGB cameras: read noise added after the curve, or before it (a sensor's order)
CAMERAS = {"camera_response", "camera_sensor"}
HIDDEN = ("clean", "ambient", "camera_response", "camera_sensor", "light_calibration", "interreflection",
          "cast_shadows", "fresnel", "fresnel_plugin", "masking", "ggx_plugin", "ggx_plastic",
          "second_lobe")

#: a power-law camera with the read noise before its curve (issue 44: colour-science has no
#: generic gamma; the exponent of the common 2.2 encoding): appended so that other kinds merge apart
GAMMA_POWER = 2.2
CAMERAS = CAMERAS | {"camera_gamma_sensor"}
HIDDEN = HIDDEN + ("camera_gamma_sensor",)
#: a GGX lobe under a dielectric coating, exactly in the library (``ggx`` + ``coating``)
HIDDEN = HIDDEN + ("coated_plugin",)
#: a lobe no effect of the library models (issue 44: the case that must name nothing)
HIDDEN = HIDDEN + ("anisotropic_lobe",)
#: Mitsuba's roughplastic with one roughness for every material: exactly in the library (``ggx`` + ``rough_coating``)
HIDDEN = HIDDEN + ("rough_plastic",)
ROUGH_PLASTIC_ALPHA = 0.4
