"""Pictures of a point cloud, coloured by a per-point field (``pip install 'pssd_fast[viz]'``:
matplotlib, imported on the first picture only)::

    from pssd_fast import pictures
    pictures.render(points, values, "picture.png", field="height")

:func:`render` draws a picture into an array and a file, :func:`figure` into a matplotlib
figure, :func:`figure_set` the paper's set of pictures of one denoising run. The modules behind
them: :mod:`.draw` (pictures and files), :mod:`.view` (up axes, views, framing), :mod:`.colours`
(colour scales, LiDAR classes, RGB), :mod:`.fields` (the fields ``pssd render`` colours by) and
:mod:`.splat` (the z-buffer).
"""
from .colours import ASPRS_CLASSES, STYLES
from .draw import COLOR_FIELDS, IMAGE_FORMATS, figure, figure_set, image_format, render
from .view import choose_up, choose_view, height

__all__ = ["ASPRS_CLASSES", "COLOR_FIELDS", "IMAGE_FORMATS", "STYLES", "choose_up",
           "choose_view", "figure", "figure_set", "height", "image_format", "render"]
