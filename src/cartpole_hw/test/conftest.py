"""cartpole_hw tests: hypothesis keeps no example database in the work tree."""
from hypothesis import settings

settings.register_profile('cartpole_hw', database=None, deadline=None)
settings.load_profile('cartpole_hw')
