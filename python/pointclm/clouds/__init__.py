"""The stages of :func:`pointclm.register_point_clouds`, one module each, in the order a call
runs them: the scan's sensor and description (:mod:`.sensor`), the run every pass shares and
its matching (:mod:`.run`), verification of the first pass (:mod:`.verification`), peeling
(:mod:`.peeling`), the final ranking with turned alternatives (:mod:`.ranking`), and the
diagnosis of an empty or doubtful result (:mod:`.diagnosis`). The results are in
:mod:`.results`; :mod:`pointclm.point_clouds` holds the one-call function that runs them.
"""
