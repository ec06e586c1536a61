"""tractionecu: online traction parameter identification and ground-condition mapping.

Implements Kobelski, Osinenko & Streif, "A method of online traction parameter
identification and mapping" (IFAC-PapersOnLine 2020, doi:10.1016/j.ifacol.2020.12.909)
as an on-board service. All physical quantities are SI unless a name says otherwise.
"""

__version__ = "0.1.0"
