"""The names of the observation settings, the learning methods and the reference actors, with
their labels, colours and short names, defined once for the registries, tables and figures.
Imports nothing, so that the report learns every name without loading JAX. A setting or
method registered at run time without an entry here is labelled by its name.
"""

from __future__ import annotations

# The six observation settings of the paper, in Table I column order (observation PRESETS names).
SETTINGS: tuple[str, ...] = ("full", "gaussian_noise", "circular_r4", "circular_r6", "conic_r4",
                             "random_masking")
SETTING_TITLES: dict[str, str] = {  # panel titles, as in the paper's Table I
    "full": "Full obs",
    "gaussian_noise": "Gaussian noise (σ=3 m)",
    "circular_r4": "Circular FoV (r=4 m)",
    "circular_r6": "Circular FoV (r=6 m)",
    "conic_r4": "Conic FoV (r=4 m, α=2π/3)",
    "random_masking": "Random masking (p=0.7)",
    "occlusion": "Line-of-sight occlusion",
}
SETTING_LABELS: dict[str, tuple[str, str]] = {  # two header lines, as in the paper's Table I
    "full": ("Full obs", ""),
    "gaussian_noise": ("Gaussian", r"noise ($\sigma$=3)"),
    "circular_r4": ("Circular", "FoV (r=4)"),
    "circular_r6": ("Circular", "FoV (r=6)"),
    "conic_r4": ("Conic FoV", r"(r=4, $\alpha=\frac{2}{3}\pi$)"),
    "random_masking": ("Random", "masking (p=0.7)"),
}
SETTING_SHORT: dict[str, str] = {  # table columns and figure axes
    "full": "Full", "gaussian_noise": "Gauss σ=3", "circular_r4": "Circ r=4",
    "circular_r6": "Circ r=6", "conic_r4": "Conic r=4", "random_masking": "Mask p=.7",
    "occlusion": "Occlusion",
}


def setting_short(name: str) -> str:
    return SETTING_SHORT.get(name, name)


def setting_labels(name: str) -> tuple[str, str]:
    """A setting's two header lines for the LaTeX tables."""
    return SETTING_LABELS.get(name) or (setting_short(name), "")


# Learned methods compared in Table I, and reference rows that need no training.
BC, BC_RL = "bc", "bc_rl"
EXPERT, CONSTANT_VELOCITY = "expert", "constant_velocity"
METHODS: tuple[str, ...] = (BC_RL, BC)
REFERENCES: tuple[str, ...] = (EXPERT, CONSTANT_VELOCITY)
# Every shipped learning method, in the method registry's order: its label and colour
LEARNED: dict[str, tuple[str, str]] = {
    BC: ("BC", "#4C9BE8"), BC_RL: ("BC-RL", "#F28E2B"), "dagger": ("DAgger", "#59A14F"),
    "advisor": ("ADVISOR", "#B07AA1"),
}
METHOD_COLOURS: dict[str, str] = {name: colour for name, (_, colour) in LEARNED.items()}
METHOD_LABELS: dict[str, str] = {  # the learned methods' labels, then the references'
    **{name: label for name, (label, _) in LEARNED.items()},
    EXPERT: "Expert (discretised replay)", CONSTANT_VELOCITY: "Constant velocity",
}

# Seeds of the gpu profile: 4x the laptop's, so each cell's minimum detectable effect is about
# half the laptop's (it shrinks as 1/sqrt(seeds) where the seed level dominates).
GPU_SEEDS = 12
