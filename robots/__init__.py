"""Description files shipped with chainspace (URDF robots and skeleton files).

This folder is installed as the package ``chainspace.robots`` so that the files are found from an
installed chainspace too; use :func:`chainspace.shipped` and :func:`chainspace.list_shipped`.
"""
