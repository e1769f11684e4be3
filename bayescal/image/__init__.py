"""Images: reading laser images and extracting the laser pixels with their covariances.

See ``docs/architecture.md`` for the layers and what each may import.
"""
