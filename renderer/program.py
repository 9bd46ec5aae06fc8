"""GLSL programs built from the shader files in ``renderer/shaders``."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from renderer.context import GL

#: Directory holding the GLSL sources.
SHADER_DIR = Path(__file__).resolve().parent / "shaders"

_STAGES = {".vert": GL.GL_VERTEX_SHADER, ".frag": GL.GL_FRAGMENT_SHADER}


class ShaderError(RuntimeError):
    """A shader failed to compile or a program failed to link; the message holds the file name and info log."""


def _decode(log: bytes | str) -> str:
    return (log.decode(errors="replace") if isinstance(log, bytes) else log).strip()


def _declared_uniforms(source: str) -> set[str]:
    """Names of the uniforms a GLSL source declares (arrays by their name, without the brackets)."""
    return set(re.findall(r"^\s*uniform\s+\w+\s+(\w+)", source, flags=re.MULTILINE))


_INCLUDE = re.compile(r'^#include "([\w.]+)"[ \t]*$', flags=re.MULTILINE)


def _source(path: Path) -> str:
    """The GLSL source of ``path`` with each ``#include "NAME"`` line replaced by the file NAME beside it (once, not
    nested): code that several shaders share."""
    try:
        text = path.read_text(encoding="utf-8")
        return _INCLUDE.sub(lambda m: (path.parent / m.group(1)).read_text(encoding="utf-8"), text)
    except OSError as error:
        raise ShaderError(f"{path}: cannot read shader source: {error}") from error


def _compile(path: Path, defines: Mapping[str, int]) -> int:
    stage = _STAGES.get(path.suffix)
    if stage is None:
        raise ShaderError(f"{path}: unknown shader stage (expected one of {', '.join(_STAGES)})")
    source = _source(path)
    if defines:  # after the #version line, which must come first
        version, _, rest = source.partition("\n")
        source = "\n".join([version, *(f"#define {name} {value}" for name, value in defines.items()), rest])
    shader = GL.glCreateShader(stage)
    GL.glShaderSource(shader, source)
    GL.glCompileShader(shader)
    if not GL.glGetShaderiv(shader, GL.GL_COMPILE_STATUS):
        log = _decode(GL.glGetShaderInfoLog(shader))
        GL.glDeleteShader(shader)
        raise ShaderError(f"{path}: compile failed:\n{log}")
    return shader


class Program:
    """A linked GLSL program with named uniform setters.

    Parameters
    ----------
    *names
        Shader file names in :data:`SHADER_DIR` (or absolute paths); the stage comes from the suffix
        (``.vert`` or ``.frag``).
    defines
        Preprocessor macros (name -> integer value) defined in every stage, after its ``#version`` line: a variant
        of the program with only the features a scene needs.
    """

    def __init__(self, *names: str, defines: Mapping[str, int] | None = None) -> None:
        self.paths = [SHADER_DIR / name for name in names]
        self.declared: set[str] = set()
        shaders: list[int] = []
        try:
            for path in self.paths:
                shaders.append(_compile(path, defines or {}))
                self.declared |= _declared_uniforms(_source(path))
            self.handle = GL.glCreateProgram()
            for shader in shaders:
                GL.glAttachShader(self.handle, shader)
            GL.glLinkProgram(self.handle)
        finally:
            for shader in shaders:
                GL.glDeleteShader(shader)
        if not GL.glGetProgramiv(self.handle, GL.GL_LINK_STATUS):
            log = _decode(GL.glGetProgramInfoLog(self.handle))
            GL.glDeleteProgram(self.handle)
            raise ShaderError(f"{', '.join(str(p) for p in self.paths)}: link failed:\n{log}")
        self._locations: dict[str, int] = {}

    def use(self) -> None:
        """Make this the current program."""
        GL.glUseProgram(self.handle)

    def location(self, name: str) -> int:
        """The uniform's location; -1 (setting it does nothing) for one the sources declare but this variant of the
        program does not use (its defines compiled the code that reads it away). ShaderError for a name the sources
        do not declare."""
        if name not in self._locations:
            location = GL.glGetUniformLocation(self.handle, name)
            if location < 0 and re.sub(r"\[\d+\]$", "", name) not in self.declared:
                files = ", ".join(p.name for p in self.paths)
                raise ShaderError(f"{files}: no uniform named {name!r}")
            self._locations[name] = location
        return self._locations[name]

    def set_vec3(self, name: str, value: np.ndarray | tuple[float, float, float]) -> None:
        """Set a ``vec3`` uniform of the current program."""
        GL.glUniform3f(self.location(name), *(float(v) for v in np.asarray(value, dtype=float).reshape(3)))

    def set_mat3(self, name: str, matrix: np.ndarray) -> None:
        """Set a ``mat3`` uniform from a row-major (3, 3) array."""
        GL.glUniformMatrix3fv(self.location(name), 1, GL.GL_TRUE, np.asarray(matrix, dtype=np.float32))

    def set_mat4(self, name: str, matrix: np.ndarray) -> None:
        """Set a ``mat4`` uniform from a row-major (4, 4) array."""
        GL.glUniformMatrix4fv(self.location(name), 1, GL.GL_TRUE, np.asarray(matrix, dtype=np.float32))

    def release(self) -> None:
        """Delete the program."""
        GL.glDeleteProgram(self.handle)


_shared: dict[tuple, Program] = {}


def shared_program(*names: str, defines: Mapping[str, int] | None = None) -> Program:
    """The :class:`Program` of these shader files and defines, compiled once per process (the process has one
    context, :mod:`renderer.context`) and kept for every later pass."""
    key = (names, tuple(sorted((defines or {}).items())))
    if key not in _shared:
        _shared[key] = Program(*names, defines=defines)
    return _shared[key]
