"""Clearer errors from Mitsuba's scene parameters (mi.traverse) where a
nanovdbvolume's values are asked for and are not a parameter.

A nanovdbvolume exposes its values as the differentiable parameter `data`
only when loaded with differentiable=true, on a JIT variant (it then holds
them as an index grid and one array; otherwise it keeps the grid as the file
has it, with no copy). Asked for `...data` otherwise, Mitsuba raises a bare
KeyError naming the key; this says why, and what to change:

    KeyError: "'medium.sigma_t.data': the nanovdbvolume 'cloud.nvdb' at
    'medium.sigma_t' was loaded without differentiable=true, so its values
    are not a parameter: ..."

setup() installs it (once per process), around SceneParameters'
__getitem__ and __setitem__; every other key and error is left as it is.
"""
import re


class MissingParameter(KeyError):
    """A KeyError whose message reads as a sentence (KeyError's str() is
    its argument's repr)"""

    def __str__(self):
        return str(self.args[0])


def why_missing(params, key):
    """The reason `key` is not in `params` when it names a nanovdbvolume's
    values (`<volume>.data`), else None"""
    prefix, _, name = key.rpartition(".")
    if name != "data" or not prefix or key in params.properties:
        return None
    # (every nanovdbvolume exposes its grid facts: grid_type among them)
    fact = params.properties.get(prefix + ".grid_type")
    if fact is None:
        return None
    node = fact[2]
    match = re.search(r'filename = "([^"]*)"', str(node))
    where = f"the nanovdbvolume '{match.group(1)}'" if match else "the nanovdbvolume"
    import mitsuba as mi
    if not mi.variant() or mi.variant().startswith("scalar"):
        return (f"'{key}': {where} at '{prefix}' has no differentiable parameters in the "
                f"variant {mi.variant()}: differentiable=true needs a JIT variant (llvm_ad_*, "
                "cuda_ad_*)")
    if prefix + ".channels" in params.properties and int(params[prefix + ".channels"]) == 6:
        return (f"'{key}': {where} at '{prefix}' has 6 channels, which cannot be "
                "differentiable: split it into two 3-channel volumes")
    return (f"'{key}': {where} at '{prefix}' was loaded without differentiable=true, so its "
            "values are not a parameter: add \"differentiable\": True to its dictionary (or "
            "<boolean name=\"differentiable\" value=\"true\"/> in XML) to optimize them")


def install(mi):
    """Wraps mi.SceneParameters' item access (once)"""
    cls = mi.SceneParameters
    if getattr(cls, "_nanovdb_explained", False):
        return

    def explained(method):
        def wrapper(self, key, *args):
            try:
                return method(self, key, *args)
            except KeyError:
                reason = why_missing(self, key)
                if reason is None:
                    raise
                raise MissingParameter(reason) from None
        wrapper.__name__ = method.__name__
        wrapper.__doc__ = method.__doc__
        return wrapper

    cls.__getitem__ = explained(cls.__getitem__)
    cls.__setitem__ = explained(cls.__setitem__)
    cls._nanovdb_explained = True
