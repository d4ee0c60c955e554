"""What every figure of lidar_sim_ros shares: canvas, axis labels, colours, material names."""
from __future__ import annotations

from typing import Sequence

from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

DPI = 150
NO_MATERIAL = 255  # same code as core.pipeline.NO_MATERIAL: a return not on the target
AZ_LABEL = 'azimuth [deg] (+ = left, REP-103)'
EL_LABEL = 'elevation [deg]'

# The rocket body's surfaces (paper Secs. 5-6) and the box-wing satellite's
# (config/materials_box_wing.yaml); a material not listed keeps its own name.
MATERIAL_GLOSSARY = {
    'PIF': 'poly-isocyanate foam (insulation)',
    'MLI': 'multi-layer insulation',
    'PAF': 'payload attachment fitting',
    'PSS': 'payload support structure',
    'NOZZLE': 'engine nozzle',
    'BULKHEAD': 'bulkhead',
    'ADAPTER': 'adapter',
    'SOLAR_ARRAY': 'solar cells under cover glass',
    'WHITE_PAINT': 'white radiator paint',
    'ALUMINIUM': 'bare aluminium (antenna, booms)',
}


def _distinct_colours() -> list[tuple[float, float, float]]:
    """Up to 40 colours, no two equal: the dark then the light tab20 hues, then tab20b's."""
    tab20, tab20b = colormaps['tab20'].colors, colormaps['tab20b'].colors
    return ([tab20[i] for i in range(0, 20, 2)] + [tab20[i] for i in range(1, 20, 2)]
            + [tab20b[i] for i in (0, 4, 8, 12, 16, 2, 6, 10, 14, 18, 1, 5, 9, 13, 17,
                                   3, 7, 11, 15, 19)])


_COLOURS = _distinct_colours()


def palette(n: int) -> list[tuple[float, float, float]]:
    """``n`` colours for ids 0..n-1, all different while n <= 40 (then they repeat)."""
    return [_COLOURS[i % len(_COLOURS)] for i in range(n)]


def material_label(material_id: int, names: Sequence[str]) -> str:
    """``'PIF: poly-isocyanate foam (insulation)'``; numbered if the name is unknown."""
    if material_id == NO_MATERIAL:
        return 'no material (false return)'
    if material_id >= len(names):
        return f'material {material_id}'
    name = names[material_id]
    full = MATERIAL_GLOSSARY.get(name.upper())
    return f'{name}: {full}' if full and full.lower() != name.lower() else name


def new_figure(size: tuple[float, float]) -> Figure:
    """A constrained-layout figure on its own Agg canvas (pyplot's backend untouched)."""
    fig = Figure(figsize=size, layout='constrained')
    FigureCanvasAgg(fig)
    return fig
