"""A scene's white: the luminance of a white card in its light, the reference a tone curve maps to display white.

A camera is exposed so that a white card in the subject's light comes out white; the tone curve then keeps that
exposure for every frame and every product under the same light. The card here is a perfect white Lambert surface
at the camera's target, turned to face the light at its brightest, unshadowed::

    W = max over unit n of  Y( sum_i E_i g_i max(n . l_i, 0)  +  I E_env(n) / pi )

with, for light i, ``E_i`` its radiance (linear RGB; a white Lambert surface facing it renders as ``E_i``, see
:class:`renderer.scene.DirectionalLight`), ``l_i`` the unit vector towards it and ``g_i = 1`` for a directional
light, ``(d_ref / d)^2`` for a point light at distance ``d`` from the target; ``E_env(n) / pi`` the environment's
prefiltered irradiance over pi (:func:`renderer.environment.prefiltered`: a white Lambert surface of normal n renders
as it), ``I`` its intensity; ``Y = 0.2126 r + 0.7152 g + 0.0722 b`` (Rec. 709). The maximum is taken over
:data:`NORMALS` directions spread evenly on the sphere (:func:`renderer.occlusion.sphere_directions`, about 3 degrees
apart) and, for each subset S of the lights, the direction of ``sum_(i in S) Y(E_i g_i) l_i``: where the card sees
exactly the lights of S, that is where their light peaks, so that without an environment W is exact (with one, the
environment's smooth share moves the peak by a little, and the lattice finds it to within 6e-4 of W).

Because W depends on the lights and not on what a frame shows, a turntable's frames, and a line's products under one
light, share one tone curve: the same linear value gives the same display value in all of them.
"""

from __future__ import annotations

import itertools

import numpy as np

from renderer.environment import Environment, prefiltered
from renderer.occlusion import sphere_directions
from renderer.scene import DirectionalLight, Scene
from renderer.tone_map import LUMINANCE_WEIGHTS

#: Normals of the lattice the card is turned to (besides the peaks of the lights' subsets).
NORMALS = 4096


def scene_white(scene: Scene) -> float:
    """The luminance W of a white card at the camera's target in the scene's light (module docstring), in the
    render's linear units; at least 1e-6 (a scene without light). For ``tone_map(..., "reinhard", white=W)``."""
    target = np.asarray(scene.camera.target, dtype=float)
    towards, radiance = [], []  # l_i and E_i g_i of each light that can light the card
    for light in scene.lights:
        if isinstance(light, DirectionalLight):
            towards.append(light.to_light())
            radiance.append(np.asarray(light.radiance, dtype=float))
        else:
            offset = np.asarray(light.position, dtype=float) - target
            distance = float(np.linalg.norm(offset))
            if distance == 0.0:  # a light at the target lights no card there: it is inside it
                continue
            towards.append(offset / distance)
            radiance.append(np.asarray(light.radiance, dtype=float) * (light.reference_distance_mm / distance) ** 2)
    towards, radiance = np.reshape(towards, (-1, 3)), np.reshape(radiance, (-1, 3))
    luminous = towards * (radiance @ np.asarray(LUMINANCE_WEIGHTS))[:, None]  # Y(E_i g_i) l_i
    subsets = itertools.chain.from_iterable(itertools.combinations(luminous, k) for k in range(1, len(luminous) + 1))
    peaks = [peak / np.linalg.norm(peak) for peak in map(sum, subsets) if np.linalg.norm(peak) > 0.0]
    normals = np.concatenate([sphere_directions(NORMALS), np.reshape(peaks, (-1, 3))])
    card = np.maximum(normals @ towards.T, 0.0) @ radiance
    environment = scene.environment
    if environment is not None and environment.intensity > 0.0:
        irradiance = Environment(prefiltered(environment).irradiance, environment.rotation_deg, environment.intensity)
        card += irradiance.lookup(normals)
    return max(float(np.max(card @ np.asarray(LUMINANCE_WEIGHTS))), 1e-6)
