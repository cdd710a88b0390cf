"""Everything that touches pxr: plugin registration, schema helpers, scene extraction, authoring.

Numerics (``usdahd.sh``, ``usdahd.models``) never import this package.
"""
