"""The paper's evaluation protocols and tables: Table 3 / Table 5 (synthetic test programs,
:mod:`csgnet.paper.tables`), Table 4 (2D shapes without programs) and Table 6 (primitive detection)
(:mod:`csgnet.paper.protocols`). Nothing below :mod:`csgnet` imports this package."""
