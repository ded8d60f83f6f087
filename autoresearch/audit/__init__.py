"""The credibility layer (paper Sec. 3.4): every claim of a campaign denominated in measured seed noise.

One module per step, named for it: ``noise`` (Eq. noisefloor), ``verify`` (Eq. reseedgate and
promotion), ``prune`` (Eqs. loo, loodecision, prunereverify), ``random_arm`` (Eqs. randsearch,
verdict); ``stats`` holds the equations as pure functions, ``seeds`` the fresh-seed plan,
``trials`` the resumable batch of runs under all of them; what they write goes to the campaign store
(autoresearch.campaign.audit_log) and to the family's ledger (autoresearch.ledger).
"""
