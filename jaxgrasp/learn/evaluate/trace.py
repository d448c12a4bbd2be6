"""A run's chains as ArviZ's DataTree (``pip install jaxgrasp[arviz]``).

``posterior/grasp`` holds the chain positions (chain x draw x coord, coords x, y, z, qw, qx,
qy, qz), ``sample_stats`` the per-step ``accepted``, ``is_jump``, ``outcome`` and ``epsilon``
of each proposal, and ``warmup_*`` groups the burn-in steps. The run's identity is in the
attributes. ``arviz_stats`` computes ESS, R-hat and MCSE on it.
"""

import numpy as np

__all__ = ["COORDS", "to_arviz"]

COORDS = ("x", "y", "z", "qw", "qx", "qy", "qz")


def to_arviz(result, *, include_burn_in: bool = True):
    """The chains of ``result`` (a LearnResult) as an ``xarray.DataTree`` in ArviZ layout."""
    try:
        # arviz-base pulls in xarray and pandas (~110 MB): an optional extra
        import arviz_base
    except ImportError:
        raise ImportError("LearnResult.to_arviz needs ArviZ: pip install 'jaxgrasp[arviz]' "
                          "(or arviz-base)") from None
    burn = int(result.params.burn_in)

    def chain_major(a):  # (steps, chains, ...) -> (chains, draws, ...)
        return np.swapaxes(np.asarray(a), 0, 1)

    stats = {"accepted": result.accepted, "is_jump": result.is_jump,
             "outcome": result.outcomes.astype(np.int32), "epsilon": result.epsilons}
    groups = {"posterior": {"grasp": chain_major(result.positions[burn:])},
              "sample_stats": {k: chain_major(v[burn:]) for k, v in stats.items()}}
    if include_burn_in and burn:
        groups["warmup_posterior"] = {"grasp": chain_major(result.positions[:burn])}
        groups["warmup_sample_stats"] = {k: chain_major(v[:burn]) for k, v in stats.items()}
    attrs = {"object": result.object_name, "object_hash": result.object_hash,
             "workflow": result.workflow, "method": result.method, "sketch": result.sketch,
             "seed": int(result.seed), "backend": result.backend, "burn_in": burn,
             "outcome_names": "success,slipped,collision,miss"}
    tree = arviz_base.from_dict(groups, dims={"grasp": ["coord"]},
                                coords={"coord": list(COORDS)}, save_warmup=include_burn_in)
    tree.attrs.update(attrs)
    return tree
