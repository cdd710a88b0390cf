"""Rendering behind ``usdahd preview`` (issue 14).

wgpu rasterisation lives in ``usdahd.commands.preview`` for now; ``raytrace`` is the Embree
fallback used without a Vulkan adapter.
"""
