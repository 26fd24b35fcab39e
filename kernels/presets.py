"""Scene presets: the rendering conventions of SPEC section 2, as typed values.

A preset fixes the plane size (scene units), the point light's intensity and whether
radiance falls off with 1/d^2, and the roughness floor that keeps GGX finite. Every
renderer (the Warp kernels and their torch references) reads the same preset object.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

__all__ = ["RenderPreset", "PRESETS", "get_preset"]


@dataclass(frozen=True)
class RenderPreset:
    """Scene and light conventions shared by the kernels and their references.

    Attributes:
        name: preset name.
        plane_size: side of the square material plane in scene units; the plane spans
            [-plane_size/2, plane_size/2] in x and y at z = 0.
        intensity: point-light intensity per RGB channel (radiance scale).
        inverse_square: if True, radiance falls off with 1 / |p_light - x|^2.
        roughness_floor: roughness is clamped to at least this value before alpha =
            roughness^2, so the GGX lobe stays finite on mirror-like pixels.
    """

    name: str
    plane_size: float
    intensity: tuple[float, float, float]
    inverse_square: bool
    roughness_floor: float

    def with_overrides(
        self,
        *,
        plane_size: float | None = None,
        intensity: float | tuple[float, float, float] | None = None,
        inverse_square: bool | None = None,
        roughness_floor: float | None = None,
    ) -> RenderPreset:
        """Return a copy with the given fields replaced (None keeps the preset's)."""
        changes: dict = {}
        if plane_size is not None:
            if not plane_size > 0:
                raise ValueError(f"plane_size must be positive, got {plane_size}")
            changes["plane_size"] = float(plane_size)
        if intensity is not None:
            if isinstance(intensity, (int, float)):
                intensity = (float(intensity),) * 3
            if len(intensity) != 3:
                raise ValueError(f"intensity must be a scalar or 3 values, got {intensity}")
            changes["intensity"] = tuple(float(v) for v in intensity)
        if inverse_square is not None:
            changes["inverse_square"] = bool(inverse_square)
        if roughness_floor is not None:
            if not 0.0 <= roughness_floor < 1.0:
                raise ValueError(f"roughness_floor must be in [0, 1), got {roughness_floor}")
            changes["roughness_floor"] = float(roughness_floor)
        return replace(self, **changes)


_PI = 3.141592653589793

PRESETS: dict[str, RenderPreset] = {
    # The paper's own setup (SPEC section 2): plane of side 4, intensity pi, no falloff,
    # roughness floor 0.0993 as in the authors' renderer.
    "dgrsise": RenderPreset("dgrsise", 4.0, (_PI, _PI, _PI), False, 0.0993),
    # MaterialGAN / Luo et al. 2024 captures: positions in cm, light power 1500 per
    # channel, 1/d^2 falloff. The plane size comes from each capture's image_size.txt;
    # 17.0 cm is only the fallback used when a capture does not say.
    "materialgan": RenderPreset("materialgan", 17.0, (1500.0, 1500.0, 1500.0), True, 0.0993),
    # Deschaintre et al. 2018 (INRIA data): plane [-1, 1], intensity pi, no falloff.
    "deschaintre": RenderPreset("deschaintre", 2.0, (_PI, _PI, _PI), False, 0.0993),
}


def get_preset(preset: str | RenderPreset) -> RenderPreset:
    """Look a preset up by name (or pass a RenderPreset through)."""
    if isinstance(preset, RenderPreset):
        return preset
    if not isinstance(preset, str):
        raise TypeError(f"preset must be a name or a RenderPreset, got {type(preset).__name__}")
    try:
        return PRESETS[preset]
    except KeyError:
        raise ValueError(f"unknown preset {preset!r}; known: {sorted(PRESETS)}") from None
