"""`llmnav view`: self-contained HTML pages of runs and sweeps, and episode videos.

`model` arranges a run folder by decision, `drawing` turns geometry into numbers for SVG, `page`
renders the Jinja2 templates in `templates/` and writes the pages, `video` renders an episode to MP4
or GIF. Everything reads run folders through `llmnav.runlog` and `llmnav.score`.
"""
