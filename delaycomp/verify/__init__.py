"""Verification: the reference cases (``.cases``), the cross-check table
(``.check``), the FMU cross-check files (``.crosscheck``), and the runs in other
masters: the container FMU (``.container``), libcosim and Ecos (``.thirdparty``),
OMSimulator (``.omsimulator``).
"""
