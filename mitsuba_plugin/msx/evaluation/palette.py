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


def color(label: str) -> str:
    """The colour of a row label ('correlated bdpt' → correlated's) or a model name."""
    if label.startswith("Smith"):  # the Smith model's entry (heitz = invariance): heitz's colour
        return MODEL_COLORS["heitz"]
    return MODEL_COLORS.get(label, MODEL_COLORS.get(label.split(" ")[0], "0.3"))
