"""The report of a workspace: a static HTML site with a 3-D skeleton player.

``mocapflow report WORKSPACE [--output DIR]`` (:mod:`.plugin`) reads the workspace through
the catalog and the datasets API (:mod:`.model`), and writes a site that works from
``file://`` with no network (:mod:`.site`): the page, its own small JavaScript
(``assets/``), and the motion data as compact binary data scripts (:mod:`.blobs`).
"""
