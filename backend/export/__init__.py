"""``python -m backend export JOB --format FORMAT``: a rendered job's labels as a training dataset (docs/design.md
§15).

``command.py`` is the command (render what is missing, read the per-frame labels and layers, write the destination
whole); its ``FORMATS`` names each format's writer, a module named after the format (their labels and descriptions:
``core.backend_protocol.EXPORT_FORMATS``): pure functions of the job (``core.job.Job``), the per-frame labels
(``core.labels``' schema), the instance layers and the image files; ``common.py`` holds the pixel convention they
share. Readers of the formats (pycocotools, vcd) are test tools only: never imported here.
"""
