"""The site store seen from btrun's runs (the store itself: the top-level ``store``
package, docs/store.md).

* :mod:`nodes.site.recording` - a run's inventory rows recorded as the run writes them;
  run folders imported;
* :mod:`nodes.site.cli` - ``btrun inventory history|diff|runs|import``.
"""
