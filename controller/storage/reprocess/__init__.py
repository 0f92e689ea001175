"""Storage for archive reprocessing: what it reads from a record store (campaigns, archived
frame pairs, current models) and the database it writes. May import :mod:`controller.storage`
and the layers below it.
"""
