"""A layer stack's data for the shading program (``shaders/km_layers.frag``): a channel stack's optical tables,
thickness maps, substrate and its conversion to RGB as textures and uniforms, or a precomposed stack's planes as a 2-D
array texture, in the layouts km_layers.frag documents, checked on the way."""

from __future__ import annotations

import numpy as np

from renderer.context import GL
from renderer.program import Program
from renderer.stack import MAX_CHANNELS, MAX_LAYERS, ChannelStack, Precomposed
from renderer.textures import float_texture, map_texels
from renderer.uniforms import COMPOSITE_UNIT, SUBSTRATE_UNIT


def table_texels(x: np.ndarray, r0: np.ndarray, t: np.ndarray, groups: int) -> np.ndarray:
    """Texels (2 groups + 1, n, 4) of one table in the layout documented in km_layers.frag."""
    n, channels = r0.shape
    texels = np.zeros((2 * groups + 1, n, 4))
    padded = np.zeros((2, n, 4 * groups))
    padded[0, :, :channels], padded[1, :, :channels] = r0, t
    texels[: 2 * groups] = padded.reshape(2, n, groups, 4).transpose(0, 2, 1, 3).reshape(2 * groups, n, 4)
    texels[2 * groups, :, 0] = x
    return texels


def channel_uniforms(stack: ChannelStack) -> dict:
    """Validated per-draw data of a channel stack (bottom-up), as the shader wants it."""
    if stack.n_layers > MAX_LAYERS:
        raise ValueError(f"at most {MAX_LAYERS} layers can be composited, got {stack.n_layers}")
    if len(stack.thicknesses) != stack.n_layers:
        raise ValueError(
            f"one thickness per layer is needed: {stack.n_layers} tables, {len(stack.thicknesses)} thicknesses"
        )
    # From here on bottom-up, the order of the composition: index 0 lies on the substrate.
    tables, thicknesses = list(stack.tables)[::-1], list(stack.thicknesses)[::-1]
    substrate = np.asarray(stack.substrate, dtype=float)
    if substrate.ndim != 1 or not 1 <= substrate.size <= MAX_CHANNELS:
        raise ValueError(f"substrate must have shape (C,) with 1 <= C <= {MAX_CHANNELS}, got {substrate.shape}")
    channels = substrate.size
    if not (np.all(np.isfinite(substrate)) and substrate.min() >= 0.0 and substrate.max() <= 1.0):
        raise ValueError("substrate albedo must lie in [0, 1]")
    to_rgb = stack.to_rgb
    if to_rgb is None:
        if channels != 3:
            raise ValueError(f"{channels} channels need a ({channels}, 3) to_rgb matrix")
        to_rgb = np.eye(3)
    to_rgb = np.asarray(to_rgb, dtype=float)
    if to_rgb.shape != (channels, 3):
        raise ValueError(f"to_rgb must have shape ({channels}, 3), got {to_rgb.shape}")
    arrays = [table.arrays() for table in tables]
    for index, (_, r0, _) in enumerate(arrays):
        if r0.shape[1] != channels:
            raise ValueError(
                f"layer {len(tables) - 1 - index} (top first): the table has {r0.shape[1]} channels, "
                f"the substrate {channels}"
            )
    maps: list[np.ndarray | None] = []
    uniform = np.zeros(MAX_LAYERS)
    for index, thickness in enumerate(thicknesses):
        value = np.asarray(thickness, dtype=float)
        if value.ndim not in (0, 2) or value.size < 1 or not np.all(np.isfinite(value)):
            raise ValueError(
                f"layer {len(tables) - 1 - index} (top first): thickness must be a finite number or a 2-D map (mm)"
            )
        if value.ndim == 0:
            uniform[index] = value
            maps.append(None)
        else:
            maps.append(value)
    substrate_map = None
    if stack.substrate_map is not None:
        weights, basis = (np.asarray(a, dtype=float) for a in stack.substrate_map)
        if weights.ndim != 3 or weights.shape[2] != 3 or basis.shape != (3, channels):
            raise ValueError(
                f"substrate_map needs weights (rows, columns, 3) and a basis (3, {channels}); got {weights.shape} "
                f"and {basis.shape}"
            )
        if not (np.all(np.isfinite(weights)) and np.all(np.isfinite(basis))):
            raise ValueError("substrate_map must be finite")
        substrate_map = (weights, basis)
    return {
        "arrays": arrays, "maps": maps, "uniform": uniform, "substrate": substrate, "to_rgb": to_rgb,
        "substrate_map": substrate_map,
    }  # fmt: skip


def composite_texels(stack: Precomposed) -> np.ndarray:
    """Texels (3 + n_layers, rows, columns, 4) of a precomposed stack, layout of km_layers.frag; row 0 at v = 0."""
    planes = [np.asarray(stack.reflectance, dtype=float), np.asarray(stack.over_black, dtype=float)]
    attenuation = np.asarray(stack.attenuation, dtype=float)
    if not 1 <= stack.n_layers <= MAX_LAYERS:
        raise ValueError(f"a precomposed stack needs 1 to {MAX_LAYERS} layers, got {stack.n_layers}")
    grid = planes[0].shape[:-1] if planes[0].ndim == 3 else ()
    if (
        planes[0].shape not in ((3,), (*grid, 3))
        or planes[0].ndim not in (1, 3)
        or planes[1].shape != planes[0].shape
        or attenuation.shape != (stack.n_layers + 1, *planes[0].shape)
    ):
        raise ValueError(
            "a precomposed stack needs reflectance and over_black (3,) with attenuation (n_layers + 1, 3), or "
            "(rows, columns, 3) with attenuation (n_layers + 1, rows, columns, 3); got "
            f"{planes[0].shape}, {planes[1].shape} and {attenuation.shape}"
        )
    # km_layers.frag: over the substrate, over black, the substrate's attenuation, then the films bottom-up.
    layers = np.stack([*planes, attenuation[-1], *attenuation[-2::-1]])
    if not np.all(np.isfinite(layers)):
        raise ValueError("a precomposed stack must be finite")
    layers = layers.reshape(len(layers), *(grid or (1, 1)), 3)
    texels = np.zeros((*layers.shape[:3], 4), dtype=np.float32)
    texels[..., :3] = layers[:, ::-1]  # row 0 of an image is the top (v = 1); texture row 0 is v = 0
    return texels


def bind_precomposed(texture: int) -> None:
    GL.glActiveTexture(GL.GL_TEXTURE0 + COMPOSITE_UNIT)
    GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, texture)


def even_axis(x: np.ndarray) -> tuple[float, float]:
    """(first sample, 1 / spacing) of a thickness axis (mm) whose samples lie within a quarter spacing of an even
    spacing, so that the shader's segment from the spacing is off by at most one, which it corrects; else (0, 0), and
    the shader searches the axis."""
    if x.size < 2:
        return 0.0, 0.0
    spacing = (x[-1] - x[0]) / (x.size - 1)
    if np.max(np.abs(x - (x[0] + spacing * np.arange(x.size)))) > 0.25 * spacing:
        return 0.0, 0.0
    return float(x[0]), float(1.0 / spacing)


def bind_channel_stack(program: Program, channel: dict) -> None:
    """Set the uniforms and bind the textures of a channel stack."""
    arrays, maps, substrate = channel["arrays"], channel["maps"], channel["substrate"]
    channels = substrate.size
    groups = -(-channels // 4)
    substrate_groups = np.zeros(4 * (MAX_CHANNELS // 4))
    substrate_groups[:channels] = substrate
    to_rgb_rows = np.zeros((MAX_CHANNELS, 3))
    to_rgb_rows[:channels] = channel["to_rgb"]
    sample_count = np.ones(MAX_LAYERS, dtype=np.int32)
    axes = np.zeros((MAX_LAYERS, 2))
    for index, (x, _, _) in enumerate(arrays):
        sample_count[index] = x.size
        axes[index] = even_axis(x)
    GL.glUniform1iv(program.location("u_sample_count"), MAX_LAYERS, sample_count)
    GL.glUniform1fv(program.location("u_thickness"), MAX_LAYERS, channel["uniform"].astype(np.float32))
    GL.glUniform2fv(program.location("u_axis"), MAX_LAYERS, axes.astype(np.float32).ravel())
    GL.glUniform4fv(program.location("u_substrate"), MAX_CHANNELS // 4, substrate_groups.astype(np.float32))
    basis_groups = np.zeros((3, 4 * (MAX_CHANNELS // 4)))
    if channel["substrate_map"] is not None:
        basis_groups[:, :channels] = channel["substrate_map"][1]
    GL.glUniform4fv(
        program.location("u_substrate_basis"), 3 * (MAX_CHANNELS // 4), basis_groups.astype(np.float32).ravel()
    )
    GL.glUniform3fv(program.location("u_to_rgb"), MAX_CHANNELS, to_rgb_rows.astype(np.float32))
    # Every texture is made first and bound afterwards: creating one binds it to the active unit, which would unbind
    # what an earlier layer had put there.
    bound = {}
    for index, (x, r0, t) in enumerate(arrays):
        bound[index] = float_texture(table_texels(x, r0, t, groups), linear=False)
        if maps[index] is not None:
            bound[MAX_LAYERS + index] = float_texture(map_texels(maps[index]), linear=True)
    if channel["substrate_map"] is not None:
        bound[SUBSTRATE_UNIT] = float_texture(map_texels(channel["substrate_map"][0]), linear=True)
    for unit in [*range(2 * MAX_LAYERS), SUBSTRATE_UNIT]:
        GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
        GL.glBindTexture(GL.GL_TEXTURE_2D, bound.get(unit, 0))
