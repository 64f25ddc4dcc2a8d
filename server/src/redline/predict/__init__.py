"""Resource-usage models learnt from performance-test recordings (Wienke & Wrede, Section 6):
features of a component's communication (`features`), data sets from recordings (`dataset`),
and the model, kernel ridge regression tuned by grouped cross-validation (`model`)."""
