"""The scenario catalog: every file in manifests/scenarios/ is generated from here.

``python -m tools.scenarios`` rewrites the files; a test fails when a committed file differs
from what the catalog generates, so the JSON and its source never drift apart.
"""
