"""The assets shipped with shellsim, installed as the package data of ``shellsim_assets`` (see
``pyproject.toml``); :func:`neural.asset.shipped_assets_dir` finds them. They are never written to."""
