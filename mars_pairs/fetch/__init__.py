"""Fetch the archive: PDS indexes -> product labels and images, PLACES, orbital windows.

Everything lands under one cache root that mirrors the archive's paths (``cache.py``);
downloads are resumable, verified and atomic (``download.py``).
"""
