"""An outsider's recording generator, written from docs/formats/*.md alone.

Own physics (straight massless elastic cables, static equilibrium), own logger habits.
It does not import the project: it writes files a lab's logger could have written.
"""
