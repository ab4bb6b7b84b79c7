"""Turning run logs into the sources' tables, statistics and plots."""

import warnings

# A label in a script the plot font lacks (Chinese, Arabic, emoji) is drawn as boxes; matplotlib's warning
# for each missing glyph would only be noise on stderr, once per glyph and figure.
warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from font", category=UserWarning)
