"""Verification: the reference cases (:mod:`.cases`), the cross-check table
(:mod:`.check`), the FMU cross-check files (:mod:`.crosscheck`), and the runs in other
masters: the container FMU (:mod:`.container`), libcosim and Ecos (:mod:`.thirdparty`),
OMSimulator (:mod:`.omsimulator`).
"""
