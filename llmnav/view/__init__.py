"""`llmnav view`: self-contained HTML pages of runs and sweeps, and episode videos.

`model` arranges a run folder by decision, `basemap` draws the top view (`llmnav.reporting.topview`)
once for the page and the video, `drawing` turns geometry into numbers for SVG, `page`
renders the Jinja2 templates in `templates/` and writes the pages, `video` renders an episode to MP4
or GIF, `shot` screenshots a page with headless Chromium. Runs are read through `llmnav.runs.runlog` and
`llmnav.scoring.score`.
"""
