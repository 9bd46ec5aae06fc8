"""Shared pieces of the kmpipe benchmarks: realistic K and S, simulated drawdowns, timing, colour, tables.

Benchmarks measure speed and accuracy and print them; they never assert (speed does not go into tests).

Realistic inputs come from the RIT Artist Paint Spectral Database table of Golden Heavy Body acrylics and the
card of the bundled example samples, both from ``recipes/samples/simulated_drawdowns.py`` (shared with that
folder's ``simulate_samples.py`` and the tests; the table lives in the shared data folder,
``pigments/rit_golden_acrylic_ks.csv``, 380-750 nm every 10 nm). That table's K and S are on a relative scale
(titanium white S = 1); both are multiplied by :data:`KS_SCALE` and read as 1/mm, which keeps each paint's measured
K/S (its masstone colour) and gives a titanium white S of 10/mm, so that 10-60 um films are neither transparent nor
opaque. Mixtures follow Duncan's rule (K = sum c_i K_i, S = sum c_i S_i).
"""

from __future__ import annotations

import datetime
import gc
import hashlib
import os
import platform
import resource
import subprocess
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from kmpipe.physics.kubelka_munk import film_over_background, film_reflectance_transmittance, reflectance_infinite

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "recipes" / "samples"))  # the simulated drawdowns shared with the samples and tests
from simulated_drawdowns import rit_pigments  # noqa: E402

#: Relative K and S of the RIT table times this = coefficients per mm (titanium white S = 10/mm).
KS_SCALE = 10.0
#: Reading noise (reflectance units, one standard deviation), about the spread of repeated drawdown readings.
NOISE = 0.002
#: Film thickness range of the simulated drawdowns, mm (10-60 um).
THICKNESS_RANGE = (0.010, 0.060)
WHITE = "TitaniumWhite"


@dataclass(frozen=True)
class Pigments:
    """K and S (per mm) of each paint of the RIT table on a wavelength grid: arrays (paints, wavelengths)."""

    names: tuple[str, ...]
    wavelengths: np.ndarray
    K: np.ndarray
    S: np.ndarray

    @property
    def white(self) -> int:
        return self.names.index(WHITE)


def wavelength_grid(step: int, start: int = 380, stop: int = 780) -> np.ndarray:
    """Wavelengths start..stop (inclusive) every ``step`` nm, as float64."""
    return np.arange(start, stop + 1, step, dtype=np.float64)


def load_pigments(wavelengths: np.ndarray, kind: str = "linear") -> Pigments:
    """The RIT paints x :data:`KS_SCALE` on ``wavelengths``, the 380 and 750 nm values held beyond the table.

    ``kind``: "linear" or "pchip" (a monotone cubic without kinks at the table's wavelengths: use it where a spectrum
    that is exactly piecewise linear on the 10 nm grid would flatter 10 nm sampling); see
    ``simulated_drawdowns.Pigments.on``.
    """
    table = rit_pigments().on(wavelengths, kind)
    K = np.array([table.K[name] for name in table.names])
    S = np.array([table.S[name] for name in table.names])
    return Pigments(table.names, table.wavelengths, KS_SCALE * K, KS_SCALE * S)


def random_recipes(rng: np.random.Generator, count: int, n_pigments: int, white: int) -> np.ndarray:
    """Concentrations (count, n_pigments), rows summing to 1: titanium white plus 1 to 3 other paints.

    The colourants together take 2-60 % (log-uniform) split at random (Dirichlet(1)); white has the rest.
    """
    others = np.array([i for i in range(n_pigments) if i != white])
    C = np.zeros((count, n_pigments))
    n_colourants = rng.integers(1, 4, size=count)
    colourant_total = np.exp(rng.uniform(np.log(0.02), np.log(0.6), size=count))
    for k in (1, 2, 3):
        rows = np.flatnonzero(n_colourants == k)
        if rows.size == 0:
            continue
        chosen = np.argsort(rng.random((rows.size, others.size)), axis=1)[:, :k]
        shares = rng.dirichlet(np.ones(k), size=rows.size) * colourant_total[rows, None]
        C[rows[:, None], others[chosen]] = shares
    C[:, white] = 1.0 - colourant_total
    return C


def over_backgrounds(K, S, X, backgrounds: Sequence, out: Sequence[np.ndarray] | None = None, chunk: int = 4096):
    """Readings of films (K, S rows; X (rows, 1) mm) over each background, in chunks of rows (bounded memory).

    Each background is an array broadcastable to a row of K (e.g. (n,)). ``out``: preallocated arrays like K.
    """
    if out is None:
        out = [np.empty_like(K) for _ in backgrounds]
    for lo in range(0, K.shape[0], chunk):
        rows = slice(lo, lo + chunk)
        R0, T = film_reflectance_transmittance(K[rows], S[rows], X[rows])
        for target, G in zip(out, backgrounds, strict=True):
            target[rows] = film_over_background(R0, T, G)
    return out


def masstone(K, S, out: np.ndarray | None = None, chunk: int = 4096) -> np.ndarray:
    """R_inf of each row of K, S, in chunks."""
    if out is None:
        out = np.empty_like(K)
    for lo in range(0, K.shape[0], chunk):
        rows = slice(lo, lo + chunk)
        out[rows] = reflectance_infinite(K[rows], S[rows])
    return out


def add_noise(rng: np.random.Generator, clean: np.ndarray, sigma: float = NOISE) -> np.ndarray:
    """clean + N(0, sigma^2), made in one new array without a second full-size temporary."""
    noisy = np.empty_like(clean)
    rng.standard_normal(out=noisy)
    noisy *= sigma
    noisy += clean
    return noisy


def best_of(function: Callable[[], object], repeats: int = 3) -> tuple[float, object]:
    """Shortest wall time of ``repeats`` calls (garbage collected before each), and the last call's result."""
    best = np.inf
    result = None
    for _ in range(repeats):
        result = None
        gc.collect()
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ---------------------------------------------------------------------------------------------- colour


@cache
def _colour():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour warns at import that matplotlib is missing
        import colour
    return colour


def lab(reflectance: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """CIE Lab (D65, CIE 1931 2 degree observer) of spectra (..., n), via colour.sd_to_XYZ (ASTM E308)."""
    colour = _colour()
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    illuminant = colour.SDS_ILLUMINANTS["D65"]
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    R = np.asarray(reflectance, dtype=np.float64)
    flat = R.reshape(-1, R.shape[-1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spectra = colour.MultiSpectralDistributions(flat.T, wavelengths)
        XYZ = np.reshape(colour.sd_to_XYZ(spectra, cmfs, illuminant), (-1, 3))
    return colour.XYZ_to_Lab(XYZ / 100.0, white).reshape(*R.shape[:-1], 3)


def delta_e_2000(R_a: np.ndarray, R_b: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """|Delta E 2000| between reflectance spectra of the same shape (..., n), D65 and 2 degree observer."""
    return np.abs(_colour().delta_E(lab(R_a, wavelengths), lab(R_b, wavelengths), method="CIE 2000"))


# ---------------------------------------------------------------------------------------------- reporting


@dataclass
class Table:
    """A titled table of already formatted cells, with notes printed under it."""

    title: str
    columns: list[str]
    rows: list[list[str]]
    notes: list[str]

    def markdown(self) -> str:
        lines = [f"### {self.title}", "", "| " + " | ".join(self.columns) + " |"]
        lines.append("|" + "|".join("---" if i == 0 else "---:" for i in range(len(self.columns))) + "|")
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        if self.notes:
            lines.append("")
            lines += [f"- {note}" for note in self.notes]
        return "\n".join(lines) + "\n"

    def print(self) -> None:
        try:
            from rich.console import Console
            from rich.table import Table as RichTable
        except ImportError:  # plain text
            print(self.markdown())
            return
        table = RichTable(title=self.title, title_justify="left")
        for i, column in enumerate(self.columns):
            table.add_column(column, justify="left" if i == 0 else "right")
        for row in self.rows:
            table.add_row(*row)
        console = Console(width=160)
        console.print(table)
        for note in self.notes:
            console.print(f"  - {note}", highlight=False)
        console.print()


def sig(value: float, digits: int = 3) -> str:
    """A number to ``digits`` significant digits, plain or in e-notation when very small or large."""
    if value is None or not np.isfinite(value):
        return str(value)
    if value != 0.0 and (abs(value) < 1e-3 or abs(value) >= 1e6):
        return f"{value:.{digits - 1}e}"
    return f"{value:.{digits}g}"


def machine() -> dict[str, str]:
    """What the numbers were measured on."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        nproc = subprocess.run(["nproc"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        nproc = str(os.cpu_count())
    import nlopt
    import scipy

    def digest(relative: str) -> str:
        path = REPO / relative
        return hashlib.sha256(path.read_bytes()).hexdigest()[:12] if path.exists() else "missing"

    info = {
        "date": datetime.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z"),
        "nproc": nproc,
        "cpu": cpu,
        "memory": _memory_total(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "nlopt": nlopt.__version__,
        "colour-science": _colour().__version__,
        "OPENBLAS_CORETYPE": os.environ.get("OPENBLAS_CORETYPE", "(unset)"),
        "load average at start (1, 5, 15 min)": " ".join(f"{v:.2f}" for v in os.getloadavg()),
        "kmpipe/physics/inversion.py sha256": digest("kmpipe/physics/inversion.py"),
        "kmpipe/physics/joint_fit.py sha256": digest("kmpipe/physics/joint_fit.py"),
    }
    return info


def _memory_total() -> str:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return f"{int(line.split()[1]) / 1024**2:.1f} GiB"
    except OSError:
        pass
    return "unknown"


def stage_face(folder: Path) -> str:
    """The demo's face (recipes/scenes/face.toml) laid out in ``folder`` as the demo lays it out: each material it
    names fitted from its bundled sample into ``folder/materials``, the cosmetic maps it names copied beside it, the
    bundled head linked as ``folder/../head`` (its skin maps); returns the scene's text."""
    import tomllib

    from kmpipe.stages.fit import fit_manifests

    scenes = REPO / "recipes" / "scenes"
    text = (scenes / "face.toml").read_text(encoding="utf-8")
    layers = tomllib.loads(text)["layer"]
    (folder / "materials").mkdir(parents=True)
    names = [Path(layer["material"]).stem for layer in layers]
    fit_manifests([REPO / "recipes" / "samples" / n / "manifest.toml" for n in names], folder / "materials")
    for file in {layer["thickness_map"]["file"] for layer in layers if "thickness_map" in layer}:
        (folder / file).write_bytes((scenes / file).read_bytes())
    (folder.parent / "head").symlink_to(REPO / "recipes" / "head")
    return text
