"""kmpipe: measurements of cosmetic films to Kubelka-Munk materials and render assets.

The public API is what ``__all__`` lists: one function per pipeline stage (the CLI and ``kmpipe run`` call the same
ones), the file formats' readers and writers, and the physics. Each name is imported on first use, so ``import
kmpipe`` stays cheap (the CLI starts without loading colour-science or OpenGL)::

    >>> import kmpipe
    >>> float(kmpipe.reflectance_infinite(1.0, 4.0))  # R_inf = 1 + K/S - sqrt((K/S)^2 + 2 K/S)
    0.5

Subpackages by role: :mod:`kmpipe.physics` (Kubelka-Munk, inversions, joint fit, colorimetry), :mod:`kmpipe.formats`
(files kmpipe reads and writes), :mod:`kmpipe.validation` (checks and reports), :mod:`kmpipe.stages` (the stages),
:mod:`kmpipe.run` (product lines as graphs of cached tasks), :mod:`kmpipe.cli` (the command line).
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("kmpipe")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"

#: Public name -> the module that defines it.
_PUBLIC = {
    # stages
    "run_session": "kmpipe.stages.measure",
    "ingest": "kmpipe.stages.ingest",
    "ingest_raw": "kmpipe.stages.ingest_raw",
    "fit_manifests": "kmpipe.stages.fit",
    "fit_sample": "kmpipe.stages.fit",
    "validate_materials": "kmpipe.stages.validate",
    "validate_material": "kmpipe.validation.material",
    "plan_scene": "kmpipe.stages.render_plan",
    "plan_to_file": "kmpipe.stages.plan_file",
    "read_plan": "kmpipe.stages.plan_file",
    "renderer_scenes": "kmpipe.stages.render",
    "render_scene": "kmpipe.stages.render",
    "write_contact_sheet": "kmpipe.stages.sheet",
    "plan_run": "kmpipe.run.planning",
    "execute": "kmpipe.run.execute",
    # formats
    "read_spectra_csv": "kmpipe.formats.spectra",
    "write_spectra_csv": "kmpipe.formats.spectra",
    "load_manifest": "kmpipe.formats.manifest",
    "manifest_files": "kmpipe.formats.manifest",
    "load_sample": "kmpipe.formats.sample",
    "read_material": "kmpipe.formats.material",
    "write_material": "kmpipe.formats.material",
    "load_scene": "kmpipe.formats.scene",
    "load_recipe": "kmpipe.formats.recipe",
    # physics
    "film_reflectance_transmittance": "kmpipe.physics.kubelka_munk",
    "reflectance_over_background": "kmpipe.physics.kubelka_munk",
    "reflectance_infinite": "kmpipe.physics.kubelka_munk",
    "ks_from_reflectance_infinite": "kmpipe.physics.kubelka_munk",
    "stack_films": "kmpipe.physics.kubelka_munk",
    "hiding_thickness": "kmpipe.physics.kubelka_munk",
    "saunderson_forward": "kmpipe.physics.saunderson",
    "saunderson_inverse": "kmpipe.physics.saunderson",
    "two_constant": "kmpipe.physics.inversion",
    "black_white": "kmpipe.physics.inversion",
    "fit_joint": "kmpipe.physics.joint_fit",
    "radiance_to_reflectance": "kmpipe.physics.white",
    "reflectance_to_Lab": "kmpipe.physics.colorimetry",
    "delta_E_2000": "kmpipe.physics.colorimetry",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    """Import a public name from its module on first use (PEP 562)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'kmpipe' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
