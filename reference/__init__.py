"""Reference traces of the paper's examples, from computations independent of delaycomp.

Each ``<scenario>/<case>_ref.csv`` (with its ``.opt``) was written by the script
``<scenario>.py`` beside it, which imports nothing from delaycomp (see README.md). The
package ships them so that ``delaycomp check`` runs from a wheel.
"""
