"""A drive's tracked 3D boxes, read from the files recordings come with (docs/design.md §15): one module per format
(``nuscenes.py``, ``kitti.py``, ``openlabel.py``, ``plain.py``), what they share (``tracks.py``) and the reader that
detects the format and maps the boxes into the import's world (``reader.py``). No bpy: numpy only."""
