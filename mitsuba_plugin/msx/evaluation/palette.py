"""One colour per model, used by every chart of the evaluation and of the microgeometry comparison
(a model has the same colour everywhere on the page). Estimators of one model share its colour; charts
draw BDPT dotted."""

MODEL_COLORS = {
    "built-in": "black",
    "single": "0.45",
    "uncorrelated": "tab:orange",
    "correlated": "tab:blue",
    "heitz": "tab:red",
    "invariance": "tab:green",
    "auto": "tab:purple",
    "compensated": "tab:brown",
    "fastmsx": "tab:pink",
    "simulation": "black",
}


def generated(name: str) -> str:
    """A colour of its own for a model of the core's table that MODEL_COLORS does not name yet: a hue from the
    name's CRC-32, so that it is the same in every chart and every run."""
    import colorsys
    import zlib

    r, g, b = colorsys.hsv_to_rgb((zlib.crc32(name.encode()) % 360) / 360.0, 0.7, 0.75)
    return "#%02x%02x%02x" % (round(r * 255), round(g * 255), round(b * 255))


def color(label: str) -> str:
    """The colour of a row label ('correlated bdpt' → correlated's) or a model name; a model of the core's
    table missing from MODEL_COLORS gets a generated colour (``generated``), any other label grey."""
    from ..plugin.parameters import MODELS

    if label.startswith("Smith"):  # the Smith model's entry (heitz = invariance): heitz's colour
        return MODEL_COLORS["heitz"]
    name = label.split(" ")[0]
    if label in MODEL_COLORS or name in MODEL_COLORS:
        return MODEL_COLORS.get(label, MODEL_COLORS.get(name))
    return generated(name) if name in MODELS else "0.3"
